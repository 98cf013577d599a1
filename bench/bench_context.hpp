// A StageContext for benchmarks: runs one stage kind's run() in-process, with its parameters
// validated and defaults filled by the engine's own schema validator (as `meshflow run` does).
#pragma once

#include "engine/registry.hpp"
#include "engine/schema.hpp"
#include "engine/stage.hpp"

#include <nlohmann/json.hpp>

#include <chrono>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <vector>

namespace meshflow::bench {

inline double secs(std::chrono::steady_clock::time_point a) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - a).count();
}

class BenchContext : public StageContext {
 public:
  BenchContext(const std::string& kind, nlohmann::json params, std::vector<Artifact> in, std::filesystem::path dir)
      : p_(std::move(params)), in_(std::move(in)), dir_(std::move(dir)) {
    const StageKind* k = find_stage_kind(kind);
    if (!k) throw std::runtime_error("stage kind '" + kind + "' is not registered");
    auto issues = validate_schema(p_, *kind_schema(*k));
    if (!issues.empty()) throw std::runtime_error(kind + ": " + issues.front().pointer + " " + issues.front().message);
  }
  const nlohmann::json& params() const override { return p_; }
  const std::string& stage_name() const override { return name_; }
  const std::vector<Artifact>& inputs() const override { return in_; }
  std::filesystem::path output(const std::string& name, const std::string& type) override {
    out_ = {name, type, "", name_, dir_ / (name + std::to_string(n_++) + ".out")};
    return out_.path;
  }
  std::filesystem::path file(const std::string& v) const override { return v; }
  void progress(double, const std::string&) override {}
  void log(const std::string&) override {}
  nlohmann::json& stats() override { return st_; }
  int threads() const override { return 1; }

  Artifact out_;
  nlohmann::json st_ = nlohmann::json::object();

 private:
  nlohmann::json p_;
  std::vector<Artifact> in_;
  std::filesystem::path dir_;
  std::string name_ = "bench";
  static inline int n_ = 0;
};

}  // namespace meshflow::bench
