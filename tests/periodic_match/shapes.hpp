// Shapes for the periodic_match tests, made with OCCT in shapes.cpp (this header is OCCT-free).
#pragma once
#include <filesystem>
#include <string>
