#!/usr/bin/env bash
# The project's one test command: the Rust tests, then the Python package's tests (pytest) in a
# virtual environment .venv at the repository root, created on the first run and reused after;
# packages and the extension are reinstalled only when their inputs changed (stamp files).
set -euo pipefail
cd "$(dirname "$0")/.."

cargo test --release

VENV=.venv
if [ ! -x "$VENV/bin/python" ]; then
  python3 -m venv "$VENV"
fi
PY="$VENV/bin/python"

# Python packages the tests need: reinstalled when python/requirements-test.txt changes.
req_hash=$(sha256sum python/requirements-test.txt | cut -d' ' -f1)
if [ "$(cat "$VENV/.requirements.stamp" 2>/dev/null || true)" != "$req_hash" ]; then
  "$PY" -m pip install -q --disable-pip-version-check -r python/requirements-test.txt
  echo "$req_hash" > "$VENV/.requirements.stamp"
fi

# The extension: rebuilt when the Rust sources, manifests or the Python package change. It builds
# into the root target/ (cargo workspace), so the smlworld crate is not compiled a second time.
src_hash=$(cat Cargo.toml Cargo.lock python/Cargo.toml python/pyproject.toml \
  $(find src python/src python/smlworld -type f \( -name '*.rs' -o -name '*.py' \) | sort) | sha256sum | cut -d' ' -f1)
if [ "$(cat "$VENV/.extension.stamp" 2>/dev/null || true)" != "$src_hash" ]; then
  (cd python && VIRTUAL_ENV="$PWD/../$VENV" PATH="$PWD/../$VENV/bin:$PATH" maturin develop --release)
  echo "$src_hash" > "$VENV/.extension.stamp"
fi

# pytest exits 5 when it collected no test: that fails here as any other failure does.
"$PY" -m pytest -q python/tests
