// meshflow CAD — face-tag overrides given in a workflow (OCCT-free; used by the geometry kinds
// and heal through their `tag_overrides` parameter).
//
// Rules are a JSON array applied in order, each {tag: NAME, <one selector>}:
//   {tag: wall, faces: [3, 4]}                                        face ids of the shape
//   {tag: symmetry, plane: {point: [0,0,0], normal: [0,0,1], tolerance: 0}}
//        faces lying in the plane: every sample of the face (points along its edges and inside
//        it) within `tolerance` of the plane (0: 1e-6 of the shape's bounding-box diagonal)
//   {tag: farfield, box: {min: [x,y,z], max: [x,y,z]}}                faces whose bounding box
//        (without OCCT's tolerance enlargement) lies inside the box
// An unknown tag, a face id out of range, a missing or double selector, or a selector matching
// no face is a meshflow::StageError naming the rule (`where` prefixes the message).
#pragma once

#include "stages/cad/cad.hpp"

#include <nlohmann/json_fwd.hpp>

#include <string>
#include <vector>

namespace meshflow::cad {

// Applies `rules` (an array; null or empty: nothing) to the shape's face tags. Returns, per
// rule, the faces it tagged.
std::vector<std::vector<int>> apply_tag_rules(Shape& shape, const nlohmann::json& rules, const std::string& where);

// Sample points of a face: points along its edges and inside the trimmed face (for selectors).
std::vector<Vec3> face_samples(const Shape& shape, int face);

}  // namespace meshflow::cad
