// meshflow engine — report.html: one self-contained page per run (no network, no scripts, no
// external fonts), written beside report.json unless the workflow says `report: false`, and
// rebuilt from what a run wrote by `meshflow report OUT_DIR`.
//
// The engine writes the page's frame: the run's status and contract problems, the stage table
// (status, seconds, peak memory, cache key) and the outputs. What an artifact holds is known
// only to the folder that registers its type, so that folder may register an artifact report
// (stages/mesh_report does for "mesh": counts, quality histograms, pictures); the engine calls
// it for every artifact of that type of every stage and puts the HTML fragment it returns in
// the stage's section. A report that throws gets a line saying so; the page is still written.
//
// Determinism: the page is a function of report.json and the artifacts' bytes. Only what a run
// measures about itself changes from run to run: the stage table's status (ran or cached),
// seconds and peak memory, and the run's total seconds. (Tests that compare out/ byte for byte
// skip report.html, as they skip report.json.)
#pragma once

#include "engine/stage.hpp"

#include <nlohmann/json_fwd.hpp>

#include <filesystem>
#include <functional>
#include <string>
#include <string_view>
#include <vector>

namespace meshflow {

// One artifact of one stage of the run, as an artifact report sees it.
struct ArtifactReportInput {
  std::string stage, kind, status;       // the stage that produced it ("split", "split", "ran")
  const nlohmann::json* stats = nullptr;  // the stage's stats (an object)
  std::string artifact, type, digest;     // which artifact ("mesh", "mesh", SHA-256)
  // Its bytes (verified against the digest), or empty when they are not at hand (a page
  // rebuilt after the cache was cleaned): then only what the stats say can be shown.
  std::filesystem::path path;
  bool delivered = false;  // an output of the run (materialised in out/)
  bool invalid = false;    // the stage's result breaks its contract (status "invalid")
  int threads = 1;
  // The stage's other artifacts that are at hand (bytes verified), e.g. the per-element quality
  // a mesh stage stores beside its mesh: what the report may read instead of computing again.
  std::vector<Artifact> companions;
};

// Returns an HTML fragment: no <script>, no external references (inline SVG, data: URIs).
// It should be quick (seconds on the demo): it runs after every run.
using ArtifactReport = std::function<std::string(const ArtifactReportInput&)>;

void register_artifact_report(const std::string& type, ArtifactReport report);
const ArtifactReport* find_artifact_report(const std::string& type);  // nullptr: none

struct ArtifactReportRegistrar {
  ArtifactReportRegistrar(const std::string& type, ArtifactReport report) {
    register_artifact_report(type, std::move(report));
  }
};

// The file with the bytes of `digest` (verified), or empty when there is none.
using ArtifactLocator = std::function<std::filesystem::path(const std::string& digest)>;

// The page of a run whose report.json is `report` (with each stage's "outputs").
std::string report_html(const nlohmann::json& report, const ArtifactLocator& locate, int threads);

// Writes out_dir/report.html (atomically). Throws when it cannot be written.
void write_report_html(const std::filesystem::path& out_dir, const nlohmann::json& report,
                       const ArtifactLocator& locate, int threads);

// `meshflow report OUT_DIR`: the page again from OUT_DIR/report.json; artifacts are looked up
// in `cache_dir` (empty: the cache report.json names) and among OUT_DIR's files, by digest.
// Returns the exit code (2: no readable report.json), messages to stderr.
int rebuild_report(const std::filesystem::path& out_dir, const std::filesystem::path& cache_dir, int threads);

// Text for HTML: & < > " ' escaped.
std::string html_escape(std::string_view text);

}  // namespace meshflow
