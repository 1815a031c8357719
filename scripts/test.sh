#!/usr/bin/env bash
# The whole test suite on a fresh machine: install what is missing (cached), lint, type-check, test.
# Usage: scripts/test.sh [pytest args...]   e.g. scripts/test.sh -m unit
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$repo"
venv="${ARMNET_VENV:-$HOME/.cache/armnet/venv}"

# The whole suite: setup also builds the shipped images (setup.d/50-images.sh), once per
# content, before any test session starts: a build beside the suite's timing-sensitive tests
# took their cores for minutes. A run with pytest arguments builds an image only if a test asks.
ARMNET_SETUP_IMAGES=$([ "$#" -eq 0 ] && echo 1 || echo 0) bash scripts/setup.sh

lint() {
  echo "== ruff =="
  "$venv/bin/ruff" check .
  echo "== mypy (strict, every package) =="
  "$venv/bin/mypy"
  echo "== import-linter (checked layers, .importlinter) =="
  "$venv/bin/lint-imports" --no-cache --no-logo
}
export PATH="$venv/bin:$PATH"
if [ "$#" -gt 0 ]; then
  lint
  echo "== pytest =="
  exec "$venv/bin/python" -m pytest "$@"
fi

# The end-to-end scenarios through the node agent spend their minutes waiting (jobs
# running in containers and pods, timeouts, grace windows, a browser), so they run beside
# the rest of the suite, in pytest sessions of their own (each its own control plane, NATS
# and Podman service). Everything that needs the test-bed node (a host-wide lock) or builds
# the shipped images is in one of them: two sessions holding the node would wait for each
# other, and two building one image would build it twice. The simulator's serving thread
# runs real-time (agent/armnet_sim/pty_server.py): without it, sessions side by side
# on two cores starve the simulated servos (missed status packets).
# One group per line; files separated by spaces; each group is its own session, its files run
# in the order given. `armnet dev up` (test_dev_up.py) starts a node of its own and
# test_node_store.py runs setup's import into the node's store, so both run before the
# session's node fixture takes the host's node lock and keeps it to the end.
# The groups are balanced by measurement so that the three sessions end together: a session
# that runs on alone uses one core of two. That is why the container tier and the Helm
# chart's rendering, RBAC and lifecycle tests sit beside the agent's scenarios, and the
# local-run e2e beside the node's tests, and the unit tests of the SDK and the test bed (108 s
# alone, LeRobot's commands started in fresh interpreters) at the end of the agent's scenarios,
# and two operator process tests (the fuzzer 31 s, the operator command 28 s) beside the e2e
# (warm runs of 2026-12-02 before that move: main 14:53, agent scenarios 14:22, node 13:25;
# main 15:56, 15:00, 14:04: the main session ended last by 0.5 to 1.5 min every time).
# Three sessions, not four: the unit tests as a session of their own end the run sooner, but
# the extra CPU demand delays the kernel worker a pty hands its bytes on through, and the
# simulated servos then answer past LeRobot's 50 ms reply window (docs/testing.md, "Why three
# sessions").
side_groups=(
  "e2e/test_agent_jobs.py e2e/test_tenants.py e2e/test_client_jobs.py e2e/test_fms_local.py tests/container tests/integration/test_helm_chart.py tests/integration/test_helm_rbac.py tests/integration/test_helm_lifecycle.py tests/integration/test_operator_fuzz_manifests.py tests/unit/runtime tests/unit/testbed"
  "tests/integration/test_dev_up.py tests/integration/test_node_store.py tests/images e2e/test_pod_jobs.py tests/integration/test_testbed_node.py tests/integration/test_deviceplugin_node.py e2e/test_fms_browser.py e2e/test_local_run.py e2e/test_lerobot_robot_classes.py e2e/test_preflight.py e2e/test_unattended.py tests/integration/test_operator_cli_process.py"
)
# Each session prints its slowest tests (--durations) and test files (--file-durations, summed
# over their tests' phases: what moves when the groups are rebalanced): where the time goes.
# Every session's output is also kept in one directory; a failed run keeps it (its path is
# printed last, with each session's failures), a passing one removes it.
logs="$(mktemp -d /tmp/armnet-test-logs.XXXXXX)"
ignores=()
side_pids=()
side_logs=()
for group in "${side_groups[@]}"; do
  read -r -a files <<<"$group"
  log="$logs/side-${#side_logs[@]}.log"
  side_logs+=("$log")
  "$venv/bin/python" -m pytest --durations=15 --file-durations=10 "${files[@]}" >"$log" 2>&1 &
  side_pids+=("$!")
  for f in "${files[@]}"; do ignores+=("--ignore=$f"); done
done
# The linters run beside the sessions too (mypy alone is ~20 s of one core in a fresh
# clone); their report is printed once the main session has ended.
lint_log="$logs/lint.log"
lint >"$lint_log" 2>&1 &
lint_pid=$!
main_rc=0
"$venv/bin/python" -m pytest --durations=25 --file-durations=15 "${ignores[@]}" 2>&1 | tee "$logs/main.log" || main_rc=$?
lint_rc=0
wait "$lint_pid" || lint_rc=$?
cat "$lint_log"
failed=()
for i in "${!side_groups[@]}"; do
  rc=0
  wait "${side_pids[$i]}" || rc=$?
  echo "== pytest: ${side_groups[$i]} (run beside the rest) =="
  cat "${side_logs[$i]}"
  if [ "$rc" -ne 0 ]; then failed+=("${side_groups[$i]} (exit $rc)"); fi
done
if [ "$lint_rc" -ne 0 ]; then
  echo "lint failed (exit $lint_rc): the linters' report is above" >&2
fi
if [ "$main_rc" -ne 0 ] || [ "${#failed[@]}" -gt 0 ]; then
  # The short summary of every session, last: a CI page that shows only the end shows them all.
  echo "== failures of every session (pytest -ra lines; full output in $logs) =="
  grep -h -E '^(FAILED|ERROR) ' "$logs/main.log" "${side_logs[@]}" | cut -c1-600 || true
  echo "pytest failed: suite exit $main_rc; side groups failed: ${failed[*]:-none}" >&2
  exit 1
fi
if [ "$lint_rc" -ne 0 ]; then
  exit 1
fi
rm -rf "$logs"
