#!/usr/bin/env bash
# docs/newton/ensemble.sh for a scene whose mesh is an OBJ file (`[mesh] obj = "…"`, such as the closed
# meshes of docs/shells/closed_meshes.py and the public ones of docs/shells/public_meshes.py): runs the
# scene five times with the OBJ's vertices' z moved by 0, 1e-5, 2e-5, -1e-5, 3e-5 m and prints
# "iterations/factorizations(per-frame median/max)" of each run, sorted by iterations (the middle one is
# the median); a run that stops early is marked "!FRAMES". Extra arguments are environment assignments
# for the runs.
#
#   cargo build --release -p hinge-cli
#   python3 docs/shells/closed_meshes.py /tmp/cm
#   docs/newton/obj_ensemble.sh /tmp/cm/sd_torus.toml
#   # 1040/2648(4.5/76) 1086/2751(4.5/80) 1107/2753(5.5/89) 1111/2698(9/74) 1181/2993(8/76) (2026-12-07)
set -euo pipefail
scene=$1
shift
hinge=${HINGE:-$(dirname "$0")/../../target/release/hinge}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
dir=$(dirname "$scene")
obj=$(sed -n 's/^obj = "\(.*\)"/\1/p' "$scene" | head -1)
[ -n "$obj" ] || { echo "the scene has no \`obj = \"…\"\` line" >&2; exit 1; }
case $obj in /*) ;; *) obj="$dir/$obj" ;; esac
frames=$(sed -n 's/^frames = \([0-9]*\).*/\1/p' "$scene" | head -1)
results=()
for dz in 0 1e-5 2e-5 -1e-5 3e-5; do
  python3 - "$obj" "$dz" > "$tmp/mesh.obj" <<'PY'
import sys
dz = float(sys.argv[2])
for line in open(sys.argv[1]):
    if line.startswith("v "):
        t = line.split()
        print(f"v {t[1]} {t[2]} {float(t[3]) + dz!r}")
    else:
        print(line, end="")
PY
  sed "s|^obj = \".*\"|obj = \"$tmp/mesh.obj\"|" "$scene" > "$tmp/scene.toml"
  rm -rf "$tmp/out"
  env "$@" "$hinge" run "$tmp/scene.toml" --no-frames --out "$tmp/out" > /dev/null 2>&1 || true
  results+=("$(python3 - "$tmp/out/summary.json" "${frames:-0}" <<'PY'
import json, statistics, sys
s = json.load(open(sys.argv[1]))
a = s["frame_newton_iterations"]
short = "" if not int(sys.argv[2]) or len(a) == int(sys.argv[2]) else f"!{len(a)}"
print(f"{sum(a)}/{sum(s['frame_factorizations'])}({statistics.median(a):g}/{max(a)}){short}")
PY
)")
done
printf '%s\n' "${results[@]}" | sort -n | tr '\n' ' '
echo
