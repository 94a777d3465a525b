#!/usr/bin/env bash
# The project's one test command: the Rust tests, then the Python package's tests (pytest) in a
# virtual environment .venv at the repository root, created on the first run and reused after;
# packages are reinstalled only when python/requirements-test.txt changes (a stamp file).
#
# One build serves both halves: `cargo build --workspace --lib --bins --tests` compiles the
# `smlworld` crate once with the features of everything that uses it (its tests and the Python
# extension, features unified across the workspace) and builds the extension
# (target/release/lib_smlworld.so) in the same run; the extension is then copied into python/smlworld/ and the venv imports the package from
# python/ (a .pth file, as an editable install has; Ray's workers see it too), so no second compilation of the crate (maturin's own cargo run unifies
# features differently) happens on a change. Users still install the package with
# `pip install ./python` or `maturin develop` (docs/python.md).
set -euo pipefail
cd "$(dirname "$0")/.."

# System packages the tests need (Mesa's software Vulkan, Xvfb, xwd, the X11 libraries winit
# loads, python3-venv): installed with apt-get when missing and run as root, else the script
# stops with a message naming them (scripts/system_packages.sh).
bash scripts/system_packages.sh

VENV=.venv
if [ ! -x "$VENV/bin/python" ]; then
  python3 -m venv "$VENV"
fi
PY="$PWD/$VENV/bin/python"

# Python packages the tests need: reinstalled when python/requirements-test.txt changes.
req_hash=$(sha256sum python/requirements-test.txt | cut -d' ' -f1)
if [ "$(cat "$VENV/.requirements.stamp" 2>/dev/null || true)" != "$req_hash" ]; then
  "$PY" -m pip install -q --disable-pip-version-check -r python/requirements-test.txt
  echo "$req_hash" > "$VENV/.requirements.stamp"
fi

# PyO3's build script configures the extension for this interpreter. The first command builds
# every library (the extension's cdylib too: `cargo test` alone skips a library without tests)
# and every test with one feature resolution (dev-dependencies on), so the second finds it all
# built and only runs the tests.
export PYO3_PYTHON="$PY"
# In CI (CI=true) the test binaries are built without line tables: each of the ~40 test
# binaries links the whole crate, and line tables made each ~150 MB (a cold target of 12 GB,
# which once filled CI's disk); without them a binary is ~25 MB. A panic still names its
# message and place. Outside CI the release profile is left as Cargo.toml sets it (line tables
# for `perf` and backtraces), so a developer's build is not redone.
if [ "${CI:-}" = "true" ] && [ -z "${CARGO_PROFILE_RELEASE_DEBUG:-}" ]; then
  export CARGO_PROFILE_RELEASE_DEBUG=false
fi
# A cold build and its test binaries take several GB: say so before the linker fails halfway
# with "No space left on device".
need_kb=$((6 * 1024 * 1024))
free_kb=$(df -Pk . | awk 'NR == 2 { print $4 }')
if [ -n "$free_kb" ] && [ "$free_kb" -lt "$need_kb" ]; then
  echo "scripts/test.sh: warning: $((free_kb / 1024)) MB free on $(df -P . | awk 'NR == 2 { print $6 }'); a cold build of the tests needs about 6 GB (remove old target/ folders)" >&2
fi
cargo build --release --workspace --lib --bins --tests
# The extension the build made, where the package imports it from.
so=target/release/lib_smlworld.so
if [ ! -f "$so" ]; then
  echo "scripts/test.sh: $so is missing after cargo build --workspace" >&2
  exit 1
fi
cmp -s "$so" python/smlworld/_smlworld.abi3.so || cp "$so" python/smlworld/_smlworld.abi3.so
site=$("$PY" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
echo "$PWD/python" > "$site/smlworld-source.pth"

# pytest runs beside the Rust tests (both mostly wait: real-time runs, sockets, child
# processes; one after the other they took just over a minute on an unchanged tree, issue 25
# asks under 60 s), at the lowest priority: several Rust tests keep wall-clock time (a lab
# run against a mock motion-capture server) and must not wait for pytest's processes (one was
# 0.4 s late when pytest ran at their priority); no pytest test times the wall clock. Its
# output is printed after theirs. pytest exits 5 when it collected no test: that fails here as
# any other failure does.
pytest_log=$(mktemp)
trap 'rm -f "$pytest_log"' EXIT
nice -n 19 "$PY" -m pytest -q python/tests >"$pytest_log" 2>&1 &
pytest_pid=$!
rust=0
if cargo nextest --version >/dev/null 2>&1; then
  # cargo-nextest (on machines of this kind) runs the test binaries side by side, not one after
  # another. It does not run doc-tests; cargo test does those.
  # The doc-tests run even when a test failed, so one failure does not hide them.
  cargo nextest run --release --workspace --no-fail-fast || rust=$?
  # The Python extension (a cdylib) has no doc-tests: cargo would warn on every run.
  cargo test --release --workspace --exclude smlworld-python --doc || rust=$?
else
  cargo test --release --workspace || rust=$?
fi
# The API reference builds without a warning (a unit written [m] is not a link; issue 60 §3).
RUSTDOCFLAGS="-D warnings" cargo doc --no-deps --workspace --quiet || rust=$?
python=0
wait "$pytest_pid" || python=$?
echo "--- pytest python/tests"
cat "$pytest_log"
if [ "$rust" -ne 0 ] || [ "$python" -ne 0 ]; then
  echo "scripts/test.sh: failed (Rust tests: exit $rust, pytest: exit $python)" >&2
  exit 1
fi
