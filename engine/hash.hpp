// meshflow engine — SHA-256 (OpenSSL) of bytes and files, and the canonical JSON used for keys.
#pragma once

#include <nlohmann/json_fwd.hpp>

#include <cstddef>
#include <filesystem>
#include <string>
#include <string_view>

namespace meshflow {

std::string sha256_hex(std::string_view bytes);
// Streams the file; throws std::runtime_error naming the file when it cannot be read.
std::string sha256_file(const std::filesystem::path& file);
// Canonical text of a JSON value: keys sorted (nlohmann's object is an ordered std::map),
// no whitespace, numbers in shortest round-trip form. Equal values give equal bytes.
std::string canonical_json(const nlohmann::json& value);

}  // namespace meshflow
