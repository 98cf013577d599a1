// A StageContext for unit tests: runs a stage kind's run() in-process on files in a
// temporary folder (until/besides the engine's runner). Shared by tests/cad, tests/geometry
// and tests/heal (included as "../cad/test_context.hpp").
#pragma once

#include "engine/registry.hpp"
#include "engine/stage.hpp"

#include <nlohmann/json.hpp>

#include <atomic>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <unistd.h>
#include <vector>

namespace meshflow::testing {

inline std::filesystem::path scratch_dir(const std::string& name) {
  static std::atomic<int> n{0};
  auto d = std::filesystem::temp_directory_path() /
           ("meshflow-cadtest-" + std::to_string(::getpid()) + "-" + std::to_string(n++) + "-" + name);
  std::filesystem::create_directories(d);
  return d;
}

class TestContext : public StageContext {
 public:
  TestContext(std::string kind, nlohmann::json params, std::vector<Artifact> inputs = {},
              std::filesystem::path workflow_dir = {})
      : kind_(std::move(kind)), inputs_(std::move(inputs)), wdir_(std::move(workflow_dir)) {
    // Fill defaults from the kind's schema, as the engine does after validation.
    params_ = nlohmann::json::object();
    if (const nlohmann::json* s = schema_for(kind_)) {
      nlohmann::json props = s->value("properties", nlohmann::json::object());
      for (auto& [k, v] : props.items())
        if (v.contains("default")) params_[k] = v["default"];
    }
    for (auto& [k, v] : params.items()) params_[k] = v;
    dir_ = scratch_dir(kind_);
    name_ = kind_;
  }
  ~TestContext() override {
    std::error_code ec;
    std::filesystem::remove_all(dir_, ec);
  }

  // Runs the registered kind; returns this.
  TestContext& run() {
    const StageKind* k = find_stage_kind(kind_);
    if (!k) throw std::runtime_error("stage kind '" + kind_ + "' is not registered");
    k->run(*this);
    return *this;
  }
  // The artifact written under `name`, as the next stage would see it.
  Artifact artifact(const std::string& name) const {
    for (auto& o : outputs_)
      if (o.name == name) return o;
    throw std::runtime_error("no output '" + name + "'");
  }

  const nlohmann::json& params() const override { return params_; }
  const std::string& stage_name() const override { return name_; }
  const std::vector<Artifact>& inputs() const override { return inputs_; }
  std::filesystem::path output(const std::string& name, const std::string& type) override {
    Artifact a;
    a.name = name;
    a.type = type;
    a.stage = name_;
    a.path = dir_ / (name + ".out");
    outputs_.push_back(a);
    return a.path;
  }
  std::filesystem::path file(const std::string& v) const override {
    std::filesystem::path p(v);
    return p.is_absolute() || wdir_.empty() ? p : wdir_ / p;
  }
  void progress(double f, const std::string&) override {
    if (f < last_progress_ - 1e-12 || f < 0 || f > 1) progress_ok_ = false;
    last_progress_ = f;
  }
  void log(const std::string& line) override { log_.push_back(line); }
  nlohmann::json& stats() override { return stats_; }
  int threads() const override { return threads_; }

  std::vector<std::string> log_;
  bool progress_ok_ = true;
  int threads_ = 1;  // the thread budget the stage is given
  nlohmann::json stats_ = nlohmann::json::object();

 private:
  std::string kind_, name_;
  nlohmann::json params_;
  std::vector<Artifact> inputs_;
  std::vector<Artifact> outputs_;
  std::filesystem::path wdir_, dir_;
  double last_progress_ = 0;
};

}  // namespace meshflow::testing
