#!/usr/bin/env bash
# Build microcal's wheel and sdist (a wheel built from the sdist must hold the same files),
# install the wheel (with its dependencies from the package index) in a
# fresh virtual environment outside the source tree, and run the installed command:
# `microcal --version` and `microcal demo --quick`, then check the files the demo writes and
# that the wheel carries every file of src/microcal (templates and other package data).
#
#   scripts/check_wheel.sh            # with python3 (or PYTHON=/path/to/python3.X)
#   KEEP=1 scripts/check_wheel.sh     # keep the temporary directory to look at
set -euo pipefail

root=$(cd "$(dirname "$0")/.." && pwd)
python=${PYTHON:-python3}
tmp=$(mktemp -d "${TMPDIR:-/tmp}/microcal-wheel.XXXXXX")
if [ -z "${KEEP:-}" ]; then trap 'rm -rf "$tmp"' EXIT; else echo "check_wheel: keeping $tmp"; fi
start=$SECONDS
fail() { echo "check_wheel: FAILED: $*" >&2; exit 1; }

echo "check_wheel: building the wheel with $("$python" --version 2>&1) ($python)"
"$python" -m venv "$tmp/venv"
pip=("$tmp/venv/bin/python" -m pip --quiet --disable-pip-version-check)
"${pip[@]}" wheel --no-deps --wheel-dir "$tmp/dist" "$root"
wheels=("$tmp"/dist/microcal-*.whl)
[ "${#wheels[@]}" = 1 ] && [ -f "${wheels[0]}" ] || fail "expected one wheel in $tmp/dist"
wheel=${wheels[0]}
echo "check_wheel: built $(basename "$wheel")"

# the wheel holds every file of the package's source tree (less caches)
"$tmp/venv/bin/python" - "$wheel" "$root/src" <<'EOF'
import sys
import zipfile
from pathlib import Path

wheel, src = sys.argv[1], Path(sys.argv[2])
inside = set(zipfile.ZipFile(wheel).namelist())
expected = {
    p.relative_to(src).as_posix()
    for p in (src / "microcal").rglob("*")
    if p.is_file() and "__pycache__" not in p.parts and p.suffix != ".pyc"
}
missing = sorted(expected - inside)
if missing:
    sys.exit(f"check_wheel: FAILED: the wheel lacks {missing}")
data = sorted(n for n in expected if not n.endswith(".py"))
print(f"check_wheel: the wheel has all {len(expected)} files of src/microcal, data: {data}")
EOF

# the source distribution: built, then a wheel built from it holds the same files
"${pip[@]}" install build
"$tmp/venv/bin/python" -m build --sdist --outdir "$tmp/sdist" "$root" > "$tmp/sdist.log" 2>&1 \
    || { tail -n 30 "$tmp/sdist.log" >&2; fail "the sdist does not build"; }
sdists=("$tmp"/sdist/microcal-*.tar.gz)
[ "${#sdists[@]}" = 1 ] && [ -f "${sdists[0]}" ] || fail "expected one sdist in $tmp/sdist"
"${pip[@]}" wheel --no-deps --wheel-dir "$tmp/from-sdist" "${sdists[0]}"
from_sdist=("$tmp"/from-sdist/microcal-*.whl)
"$tmp/venv/bin/python" -c 'import sys, zipfile; names = [set(zipfile.ZipFile(w).namelist()) for w in sys.argv[1:]]; sys.exit(names[0] != names[1])' "$wheel" "${from_sdist[0]}" \
    || fail "the wheel built from the sdist holds other files than the wheel"
echo "check_wheel: built $(basename "${sdists[0]}"); the wheel built from it holds the same files"

"${pip[@]}" install "$wheel"
cd "$tmp"  # outside the source tree: the installed package, not src/, is what runs
export PYTHONPATH=
bin=$tmp/venv/bin
location=$("$bin/python" -c 'import microcal; print(microcal.__file__)')
case $location in
    "$tmp"/venv/*) ;;
    *) fail "microcal imports from $location, not from the fresh venv" ;;
esac

expected_version=$(basename "$wheel" | cut -d- -f2)
version=$("$bin/microcal" --version)
echo "check_wheel: microcal --version: $version"
case $version in
    *"$expected_version"*) ;;
    *) fail "microcal --version printed '$version', the wheel is $expected_version" ;;
esac

"$bin/microcal" demo --quick --out "$tmp/demo" > "$tmp/demo.log" 2>&1 \
    || { tail -n 30 "$tmp/demo.log" >&2; fail "microcal demo --quick exited non-zero"; }
for f in run.json measurements.csv cameras.json calibration.json results.json report.html; do
    [ -s "$tmp/demo/$f" ] || { tail -n 30 "$tmp/demo.log" >&2; fail "the demo did not write $f"; }
done
grep -q '</html>' "$tmp/demo/report.html" || fail "report.html is incomplete"
echo "check_wheel: OK: the wheel installs in a fresh venv and its demo wrote" \
    "$(cd "$tmp/demo" && ls | tr '\n' ' ')in $((SECONDS - start)) s"
