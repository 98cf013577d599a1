#!/usr/bin/python3
"""The CI snippets of the README (docs/ci/*.yml) run as a CI service would run them.

Usage: ci_snippets_test.py PROJECT_ROOT BUILD_DIR

For each snippet: its environment and its commands, in order, in a folder that looks like a
checkout (Makefile, scripts/ and build/ of this project linked in), with WORKFLOW set to a small
workflow whose golden summary the test writes first. The build command runs for real (a no-op
on a built tree); a command that installs Debian packages is checked instead (the packages it
names are installed) since a test does not reach the network. Then: exit 0, the cache filled at
the path the snippet keeps between runs; a changed parameter makes the check command fail with
exit 1, naming the differing fields, and leaves what the snippet uploads on failure.
"""
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile

import yaml

ROOT, BUILD = os.path.abspath(sys.argv[1]), os.path.abspath(sys.argv[2])
SMALL = """meshflow: 1
name: ci-small
stages:
  geometry: {kind: naca_wing, with: {chord: 1.0}}
  heal: {kind: heal, needs: [geometry]}
outputs:
  shape: {from: heal, formats: [brep]}
golden: ../golden/ci-small
"""
failures = []


def check(cond, what):
    print("ok:   " + what.splitlines()[0][:160] if cond else "FAIL: " + what)
    if not cond:
        failures.append(what)


def github(doc):
    job = next(iter(doc["jobs"].values()))
    env = dict(job.get("env", {}))
    commands, cached, uploads = [], None, None
    for step in job["steps"]:
        if "run" in step:
            commands.append(step["run"])
        elif step.get("uses", "").startswith("actions/cache@"):
            cached = step["with"]["path"]
        elif step.get("uses", "").startswith("actions/upload-artifact@"):
            check(step.get("if") == "failure()", "github: the outputs are uploaded on failure")
            uploads = step["with"]["path"].split()
    return env, commands, [cached] if cached else [], uploads or []


def gitlab(doc):
    job = next(v for k, v in doc.items() if isinstance(v, dict) and "script" in v)
    env = dict(job.get("variables", {}))
    commands = list(job.get("before_script", [])) + list(job["script"])
    check(job.get("artifacts", {}).get("when") == "on_failure", "gitlab: the outputs are uploaded on failure")
    return env, commands, [p.rstrip("/") for p in job["cache"]["paths"]], job["artifacts"]["paths"]


def installs_packages(cmd):
    m = re.search(r"apt-get install (.*)$", cmd)
    if not m:
        return None
    return [w for w in shlex.split(m.group(1)) if not w.startswith("-")]


def run(cmd, cwd, env):
    p = subprocess.run(["bash", "-e", "-c", cmd], cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                       text=True, timeout=900)
    return p.returncode, p.stdout


def one(name, parse):
    with open(os.path.join(ROOT, "docs", "ci", name)) as f:
        env_s, commands, cached, uploads = parse(yaml.safe_load(f))
    check(env_s.get("MESHFLOW_CACHE") in cached, f"{name}: the cache kept between runs is MESHFLOW_CACHE ({cached})")
    check(any("meshflow check" in c for c in commands), f"{name}: runs meshflow check")
    work = tempfile.mkdtemp(prefix="meshflow-ci-")
    try:
        for link in ("Makefile", "scripts"):
            os.symlink(os.path.join(ROOT, link), os.path.join(work, link))
        os.symlink(BUILD, os.path.join(work, "build"))
        os.makedirs(os.path.join(work, "workflows"))
        wf = os.path.join(work, "workflows", "small.yaml")
        with open(wf, "w") as f:
            f.write(SMALL)
        env = dict(os.environ)
        env.pop("CI", None)  # golden --update is refused under CI=true: the project commits its goldens
        code, out = run(f"build/meshflow golden {wf} --update --cache {work}/golden-cache", work, env)
        check(code == 0, f"{name}: the small workflow's golden summary written ({out.strip().splitlines()[-1:]})")
        env.update({k: str(v) for k, v in env_s.items()})
        env["WORKFLOW"] = "workflows/small.yaml"
        env["CI"] = "true"
        for cmd in commands:
            pkgs = installs_packages(cmd)
            if pkgs is not None:
                missing = [p for p in pkgs if subprocess.run(["dpkg-query", "-W", p], capture_output=True).returncode != 0]
                check(not missing, f"{name}: `{cmd}` (not run: no network in a test): its packages are installed {missing}")
                continue
            code, out = run(cmd, work, env)
            check(code == 0, f"{name}: `{cmd}` exits 0 (got {code}): {out[-600:]}")
        cache = os.path.join(work, env_s["MESHFLOW_CACHE"], "actions")
        check(os.path.isdir(cache) and len(os.listdir(cache)) >= 2, f"{name}: the stages were cached in {cached}")
        # a change the golden summary does not know: the check command fails, says what differs,
        # and leaves what the snippet uploads
        with open(wf, "w") as f:
            f.write(SMALL.replace("chord: 1.0", "chord: 1.1"))
        check_cmd = next(c for c in commands if "meshflow check" in c)
        code, out = run(check_cmd, work, env)
        check(code == 1, f"{name}: a changed mesh fails the check with exit 1 (got {code})")
        check("field(s) differ" in out and "outputs.shape.volume" in out, f"{name}: the failure names the fields: {out[-400:]}")
        for p in uploads:
            check(os.path.exists(os.path.join(work, p)), f"{name}: {p} exists to upload")
        check(os.path.exists(os.path.join(work, "golden", "ci-small", "summary.obtained.json")),
              f"{name}: the obtained summary is written beside the golden one")
    finally:
        shutil.rmtree(work, ignore_errors=True)


one("github-actions.yml", github)
one("gitlab-ci.yml", gitlab)
if failures:
    print(f"{len(failures)} failure(s)")
    sys.exit(1)
print("the CI snippets run as documented")
