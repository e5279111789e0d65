#!/usr/bin/env bash
# Newton iteration counts of a scene over an ensemble of nearby starts, to tell a method's effect from the
# trajectory's sensitivity (a change to Newton changes how the cloth folds, and so the counts, by up to ±15 %
# for reasons unrelated to the change). Runs the scene five times with its mesh origin's z moved by
# 0, ±1e-5, 2e-5, 3e-5 m and prints "iterations/factorizations(per-frame median/max)" of each run, sorted
# by iterations (the middle one is the median). Extra arguments are environment assignments for the runs
# (say, an experiment's switch).
#
#   cargo build --release -p hinge-cli
#   target/release/hinge scenes show drape > /tmp/drape.toml
#   docs/newton/ensemble.sh /tmp/drape.toml            # 612/1030 613/1039 614/1030 615/1019 617/1019
#   (742/1180 … 771/1213 with `geodesic_acceleration = false` under [solver])
#
# The scene must have a line `origin = [X, Y, Z]` under [mesh] (the built-in drape and anisotropic-drape do).
set -euo pipefail
scene=$1
shift
hinge=${HINGE:-$(dirname "$0")/../../target/release/hinge}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
results=()
for dz in 0 1e-5 2e-5 -1e-5 3e-5; do
  python3 - "$scene" "$dz" > "$tmp/scene.toml" <<'PY'
import re, sys
text = open(sys.argv[1]).read()
def moved(m):
    x, y, z = (float(v) for v in m.group(1).split(","))
    return f"origin = [{x!r}, {y!r}, {z + float(sys.argv[2])!r}]"
new, n = re.subn(r"^origin = \[([^\]]*)\]", moved, text, count=1, flags=re.M)
if n != 1:
    sys.exit("the scene has no `origin = [x, y, z]` line")
print(new, end="")
PY
  line=$(env "$@" "$hinge" run "$tmp/scene.toml" --no-frames --out "$tmp/out" | grep '^done')
  it=$(sed 's/.*frames, \([0-9]*\) Newton.*/\1/' <<< "$line")
  fa=$(sed 's/.*steps, \([0-9]*\) factorizations.*/\1/' <<< "$line")
  # The per-frame median and max (`summary.json`'s frame_newton_iterations).
  mm=$(python3 - "$tmp/out" <<'PY'
import glob, json, statistics, sys
s = json.load(open(glob.glob(sys.argv[1] + "/**/summary.json", recursive=True)[0]))
f = s["frame_newton_iterations"]
print(f"{statistics.median(f):g}/{max(f)}")
PY
)
  results+=("$it/$fa($mm)")
done
printf '%s\n' "${results[@]}" | sort -n | tr '\n' ' '
echo
