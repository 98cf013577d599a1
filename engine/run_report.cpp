#include "engine/run_report.hpp"

#include "engine/artifact_type.hpp"
#include "engine/fsutil.hpp"
#include "engine/hash.hpp"

#include <nlohmann/json.hpp>

#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <map>
#include <sstream>
#include <thread>
#include <algorithm>

namespace fs = std::filesystem;
using nlohmann::json;

namespace meshflow {
namespace {

std::map<std::string, ArtifactReport>& report_table() {
  static std::map<std::string, ArtifactReport> t;  // registration runs from static initialisers
  return t;
}

std::string fixed(double v, int digits) {
  char b[64];
  std::snprintf(b, sizeof b, "%.*f", digits, v);
  return b;
}

std::string str(const json& j, const char* key) {
  return j.is_object() && j.contains(key) && j[key].is_string() ? j[key].get<std::string>() : std::string();
}
double num(const json& j, const char* key) {
  return j.is_object() && j.contains(key) && j[key].is_number() ? j[key].get<double>() : 0.0;
}

// The page's style: system fonts only, nothing fetched.
const char* kStyle = R"(
body{font:14px/1.4 system-ui,-apple-system,"Segoe UI",sans-serif;margin:24px auto;max-width:1280px;padding:0 16px;color:#1d232b;background:#fff}
h1{font-size:24px;margin:0 0 4px}h2{font-size:19px;margin:28px 0 8px;border-bottom:1px solid #ccd3db}h3{font-size:16px;margin:18px 0 6px}
table{border-collapse:collapse;margin:6px 0}td,th{padding:3px 9px;border-bottom:1px solid #e3e7ec;text-align:left;vertical-align:top}
th{background:#f2f4f7}td.n{text-align:right;font-variant-numeric:tabular-nums}code{font:12px ui-monospace,monospace}
.ok{color:#17713a;font-weight:600}.invalid,.failed{color:#b3261e;font-weight:600}.note{color:#5b6570}
.err{color:#b3261e}figure{display:inline-block;margin:6px 12px 12px 0;vertical-align:top}figcaption{font-size:12px;color:#444;max-width:640px}
svg{background:#fff}.row{display:flex;flex-wrap:wrap;gap:8px}
)";

std::string status_class(const std::string& s) {
  return s == "invalid" ? "invalid" : s == "failed" ? "failed" : s == "ran" || s == "cached" ? "ok" : "note";
}

std::string head_html(const json& report) {
  std::string name = str(report, "workflow");
  return "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\n<title>meshflow: " + html_escape(name) +
         "</title>\n<style>" + kStyle + "</style></head>\n<body>\n";
}

std::string run_status_html(const json& report) {
  const bool ok = report.value("ok", false), invalid = report.value("invalid", false);
  const bool accepted = report.value("invalid_accepted", false);
  std::string verdict = ok && !invalid ? "<span class=\"ok\">ok</span>"
                        : ok && accepted ? "<span class=\"invalid\">ok (INVALID mesh accepted)</span>"
                        : invalid ? "<span class=\"invalid\">INVALID: a mesh breaks the contract</span>"
                                  : "<span class=\"failed\">FAILED</span>";
  std::string s = "<h1>" + html_escape(str(report, "workflow")) + "</h1>\n<p>" + verdict + " &middot; workflow <code>" +
                  html_escape(str(report, "file")) + "</code> &middot; " + fixed(num(report, "seconds"), 2) + " s</p>\n";
  if (report.contains("error") && report["error"].is_string())
    s += "<p class=\"err\">" + html_escape(report["error"].get<std::string>()) + "</p>\n";
  return s;
}

// "element 9811 (tet4) at (0.71, -0.18, 0.99), scaled Jacobian -0.92"
std::string where_text(const json& w) {
  std::ostringstream s;
  if (w.contains("element")) s << "element " << w["element"].dump();
  if (w.contains("type") && w["type"].is_string()) s << " (" << w["type"].get<std::string>() << ")";
  if (w.contains("face_of")) s << "face of element(s) " << w["face_of"].dump();
  if (w.contains("cad_face")) s << "CAD face " << w["cad_face"].dump();
  if (w.contains("group") && w["group"].is_string()) s << " group " << w["group"].get<std::string>();
  if (w.contains("edge")) s << "edge " << w["edge"].dump();
  if (w.contains("at") && w["at"].is_array() && w["at"].size() == 3 && w["at"][0].is_number())
    s << " at (" << fixed(w["at"][0].get<double>(), 4) << ", " << fixed(w["at"][1].get<double>(), 4) << ", "
      << fixed(w["at"][2].get<double>(), 4) << ")";
  if (w.contains("scaled_jacobian") && w["scaled_jacobian"].is_number())
    s << ", scaled Jacobian " << fixed(w["scaled_jacobian"].get<double>(), 3);
  return s.str();
}

std::string problems_html(const json& report) {
  if (!report.contains("problems") || !report["problems"].is_array() || report["problems"].empty()) return {};
  std::string s = "<h2>Problems</h2>\n<table><tr><th>stage</th><th>clause</th><th>what</th><th>where (first listed)</th></tr>\n";
  for (auto& p : report["problems"]) {
    std::string where;
    if (p.contains("where") && p["where"].is_array())
      for (auto& w : p["where"]) where += html_escape(where_text(w)) + "<br>";
    std::string what = html_escape(str(p, "what"));
    if (!str(p, "hint").empty()) what += "<br><span class=\"note\">" + html_escape(str(p, "hint")) + "</span>";
    s += "<tr><td>" + html_escape(str(p, "stage")) + "</td><td>" + html_escape(str(p, "clause")) + "</td><td>" + what +
         "</td><td>" + where + "</td></tr>\n";
  }
  return s + "</table>\n";
}

// The run-dependent part of the page: status (ran or cached), seconds, memory.
std::string stage_table_html(const json& report) {
  std::string s =
      "<h2>Stages</h2>\n<table><tr><th>stage</th><th>kind</th><th>status</th><th>seconds</th><th>peak MB</th><th>cache key</th></tr>\n";
  for (auto& st : report.value("stages", json::array())) {
    const std::string status = str(st, "status");
    const bool measured = num(st, "peak_rss_mb") > 0;
    std::string key = str(st, "key");
    s += "<tr><td><a href=\"#stage-" + html_escape(str(st, "name")) + "\">" + html_escape(str(st, "name")) + "</a></td><td>" +
         html_escape(str(st, "kind")) + "</td><td class=\"" + status_class(status) + "\">" + html_escape(status) +
         (st.value("remote", false) ? " (remote)" : "") + "</td><td class=\"n\">" +
         (measured ? fixed(num(st, "seconds"), 2) : "-") + "</td><td class=\"n\">" +
         (measured ? fixed(num(st, "peak_rss_mb"), 0) : "-") + "</td><td><code title=\"" + html_escape(key) + "\">" +
         html_escape(key.substr(0, 12)) + "</code></td></tr>\n";
    if (!str(st, "error").empty())
      s += "<tr><td></td><td colspan=\"5\" class=\"err\">" + html_escape(str(st, "error")) + "</td></tr>\n";
  }
  return s + "</table>\n";
}

std::string outputs_html(const json& report) {
  if (!report.contains("outputs") || !report["outputs"].is_object() || report["outputs"].empty()) return {};
  std::string s = "<h2>Outputs</h2>\n<table><tr><th>output</th><th>from</th><th>files</th></tr>\n";
  for (auto& [name, o] : report["outputs"].items()) {
    std::string files;
    for (auto& f : o.value("files", json::array())) files += (files.empty() ? "" : ", ") + html_escape(f.get<std::string>());
    s += "<tr><td>" + html_escape(name) + (o.value("invalid", false) ? " <span class=\"invalid\">INVALID</span>" : "") +
         "</td><td>" + html_escape(str(o, "from")) + "</td><td>" + files + "</td></tr>\n";
  }
  return s + "</table>\n";
}

bool delivered(const json& report, const std::string& stage, const std::string& artifact, const std::string& digest) {
  if (!report.contains("outputs") || !report["outputs"].is_object()) return false;
  for (auto& [name, o] : report["outputs"].items())
    if (str(o, "from") == stage && str(o, "artifact") == artifact && str(o, "digest") == digest) return true;
  return false;
}

// One stage's section: the fragment of each of its artifacts whose type has a report.
std::string stage_section_html(const json& report, const json& st, const ArtifactLocator& locate, int threads) {
  std::string body;
  for (auto& a : st.value("outputs", json::array())) {
    const ArtifactReport* rep = find_artifact_report(str(a, "type"));
    if (!rep) continue;
    ArtifactReportInput in;
    in.stage = str(st, "name");
    in.kind = str(st, "kind");
    in.status = str(st, "status");
    in.stats = &st["stats"];
    in.artifact = str(a, "name");
    in.type = str(a, "type");
    in.digest = str(a, "digest");
    in.path = locate ? locate(in.digest) : fs::path();
    in.delivered = delivered(report, in.stage, in.artifact, in.digest);
    in.invalid = in.status == "invalid";
    in.threads = threads;
    if (locate)
      for (auto& b : st.value("outputs", json::array()))
        if (str(b, "name") != in.artifact)
          if (fs::path p = locate(str(b, "digest")); !p.empty())
            in.companions.push_back({str(b, "name"), str(b, "type"), str(b, "digest"), in.stage, p});
    try {
      body += (*rep)(in);
    } catch (const std::exception& e) {
      body += "<p class=\"err\">The report of artifact " + html_escape(in.artifact) + " could not be made: " +
              html_escape(e.what()) + "</p>\n";
    }
  }
  if (body.empty()) return {};
  return "<section id=\"stage-" + html_escape(str(st, "name")) + "\">\n<h2>" + html_escape(str(st, "name")) + " (" +
         html_escape(str(st, "kind")) + ")</h2>\n" + body + "</section>\n";
}

// The cache named by report.json's "cache" (or $MESHFLOW_CACHE): objects/ab/<digest>.
fs::path cache_of(const json& report, const fs::path& option) {
  if (!option.empty()) return fs::absolute(option);
  if (!str(report, "cache").empty()) return str(report, "cache");
  if (const char* env = std::getenv("MESHFLOW_CACHE"); env && *env) return fs::absolute(env);
  return {};
}

}  // namespace

void register_artifact_report(const std::string& type, ArtifactReport report) {
  auto& t = report_table();
  if (t.count(type)) {
    std::fprintf(stderr, "meshflow: internal error: artifact report of type '%s' registered twice\n", type.c_str());
    std::abort();
  }
  t.emplace(type, std::move(report));
}

const ArtifactReport* find_artifact_report(const std::string& type) {
  auto& t = report_table();
  auto it = t.find(type);
  return it == t.end() ? nullptr : &it->second;
}

std::string html_escape(std::string_view text) {
  std::string s;
  s.reserve(text.size());
  for (char c : text) switch (c) {
      case '&': s += "&amp;"; break;
      case '<': s += "&lt;"; break;
      case '>': s += "&gt;"; break;
      case '"': s += "&quot;"; break;
      case '\'': s += "&#39;"; break;
      default: s += c;
    }
  return s;
}

std::string report_html(const json& report, const ArtifactLocator& locate, int threads) {
  std::string s = head_html(report) + run_status_html(report) + problems_html(report) + stage_table_html(report) +
                  outputs_html(report);
  for (auto& st : report.value("stages", json::array())) s += stage_section_html(report, st, locate, threads);
  return s + "<p class=\"note\">Written by meshflow from report.json; rebuild it with <code>meshflow report OUT_DIR</code>.</p>\n"
             "</body></html>\n";
}

void write_report_html(const fs::path& out_dir, const json& report, const ArtifactLocator& locate, int threads) {
  atomic_write(out_dir / "report.html", report_html(report, locate, threads), {}, /*durable=*/false);
}

int rebuild_report(const fs::path& out_dir, const fs::path& cache_dir, int threads) {
  if (threads <= 0) threads = int(std::max(1u, std::thread::hardware_concurrency()));
  json report;
  try {
    report = json::parse(read_file(out_dir / "report.json"));
    if (!report.is_object() || !report.contains("stages")) throw std::runtime_error("it is not a meshflow run's report");
  } catch (const std::exception& e) {
    std::cerr << "error: cannot read " << (out_dir / "report.json").string() << ": " << e.what()
              << ". Give the output folder of a run (out/<workflow name>/, where report.json is).\n";
    return 2;
  }
  // Candidates by digest: the cache's object, then the out/ files of outputs written as stored.
  std::map<std::string, std::vector<fs::path>> candidates;
  const fs::path cache = cache_of(report, cache_dir);
  for (auto& st : report["stages"])
    for (auto& a : st.value("outputs", json::array())) {
      std::string d = str(a, "digest");
      if (d.size() > 2 && !cache.empty()) candidates[d].push_back(cache / "objects" / d.substr(0, 2) / d);
    }
  if (report.contains("outputs") && report["outputs"].is_object())
    for (auto& [name, o] : report["outputs"].items())
      if (const ArtifactType* t = find_artifact_type(str(o, "type")))
        for (auto& f : o.value("files", json::array()))  // the stored form has the type's extension
          if (fs::path(f.get<std::string>()).extension() == t->extension)
            candidates[str(o, "digest")].push_back(out_dir / f.get<std::string>());
  ArtifactLocator locate = [&](const std::string& digest) -> fs::path {
    for (auto& p : candidates[digest]) {
      std::error_code ec;
      if (!fs::is_regular_file(p, ec)) continue;
      try {
        if (sha256_file(p) == digest) return p;
      } catch (...) {
      }
    }
    return {};
  };
  try {
    write_report_html(out_dir, report, locate, threads);
  } catch (const std::exception& e) {
    std::cerr << "error: cannot write " << (out_dir / "report.html").string() << ": " << e.what() << "\n";
    return 1;
  }
  std::cout << "wrote " << (out_dir / "report.html").string() << "\n";
  return 0;
}

}  // namespace meshflow
