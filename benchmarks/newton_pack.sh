#!/usr/bin/env bash
# Pack Newton (PyPI `newton`, the reference of `bench_tshirt --newton`) for a GPU machine whose
# Python 3.12 has numpy and torch but no network, no Warp and no Newton.
#
# Newton 1.8.0 is one pure-Python wheel (~8.6 MB). Its only hard requirement is warp-lang
# (>= 1.17), and the cloth path used by benchmarks/newton_ref.py (ModelBuilder, Mesh,
# CollisionPipeline, SolverVBD) imports nothing else but numpy. Warp travels separately
# (../shared/tools/gpu-warp-pack) and MUST include its CPU backend (WITH_CLANG=1): Newton runs
# the graph colouring and mesh adjacency kernels on the "cpu" device even for a CUDA model.
#
# Writes the ignored folder .gpu5/: the wheel and install.sh. gpu-warp-pack deletes every
# .gpuN folder, so run it first:
#   PARTS=3 WITH_CLANG=1 ../shared/tools/gpu-warp-pack 1.19.0   # .gpu1-.gpu3 warp, .gpu4 clang
#   bash benchmarks/newton_pack.sh                             # .gpu5 newton
# On the GPU machine, with .gpu5/ present (or its wheel copied to /tmp/stash/ earlier), after
# Warp's .gpu1/install.sh:   bash .gpu5/install.sh && export PYTHONPATH=/tmp/site:$PWD
#
# Usage: bash benchmarks/newton_pack.sh [NEWTON_VERSION] [EXTRA_WHEEL_SPEC...]
set -euo pipefail
ver=${1:-1.8.0}
shift || true
root=$(git rev-parse --show-toplevel)
out="$root/.gpu5"
grep -qx '/.gpu\*/' "$root/.git/info/exclude" 2>/dev/null || printf '/.gpu*/\n' >> "$root/.git/info/exclude"
rm -rf "$out"
mkdir -p "$out"
dl() {
  python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
    -d "$out" "$@"
}
dl "newton==$ver"
for spec in "$@"; do dl "$spec"; done
(cd "$out" && sha256sum ./*.whl > SHA256SUMS)
cat > "$out/install.sh" <<'EOS'
#!/usr/bin/env bash
# On the GPU machine (repository root): install Newton's wheel into /tmp/site, next to Warp.
# The wheel is taken from .gpu5/ or, when .gpu5 was sent in an earlier run, from /tmp/stash/.
set -e
if [ ! -d /tmp/site/newton ]; then
  mkdir -p /tmp/site
  whl=$(ls .gpu5/newton-*.whl /tmp/stash/newton-*.whl 2>/dev/null | head -n 1)
  [ -n "$whl" ] || { echo "no newton wheel in .gpu5/ or /tmp/stash/"; exit 1; }
  extra=$(ls "$(dirname "$whl")"/*.whl | grep -v '/newton-' || true)
  if python3 -m pip --version >/dev/null 2>&1; then
    python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site "$whl" $extra
  else  # pure-Python wheels: unpacking is installing
    for w in "$whl" $extra; do python3 -m zipfile -e "$w" /tmp/site; done
  fi
fi
PYTHONPATH=/tmp/site python3 -c "import warp, newton; print('newton', newton.__version__, 'warp', warp.config.version)" \
  || { echo "newton did not import: install Warp first (.gpu1/install.sh, with the clang part stashed)"; exit 1; }
EOS
chmod +x "$out/install.sh"
du -sh "$out"
