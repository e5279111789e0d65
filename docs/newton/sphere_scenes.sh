#!/usr/bin/env bash
# `docs/newton/ensemble.sh` over the contact scenes beyond the default drape, so that a Newton or contact
# change is judged on more than one mesh: the drape at 20×20 and 40×40 cells, `anisotropic-drape`, and
# `shell-drop` at 3 subdivisions (642 vertices) dropped on a sphere of radius 0.3 m instead of its plane.
# Prints one line per scene (five nearby starts each, sorted by iterations). Extra arguments are
# environment assignments for the runs, as for ensemble.sh (say, an experiment's switch). About 1.5 minutes.
#
#   cargo build --release -p hinge-cli
#   docs/newton/sphere_scenes.sh
#   # 2026-12-07, this build:
#   # drape-20x20        425/603(4/21) 426/606(4/18) 430/618(4/23) 431/607(4/25) 435/615(4/28)
#   # drape-40x40        703/1244(4/33) 711/1268(5.5/41) 747/1370(5/41) 751/1335(5/52) 827/1554(6.5/44)
#   # anisotropic-drape  708/1168(5/46) 710/1166(5/45) 718/1186(5/47) 718/1212(5/45) 728/1194(5/46)
#   # shell-on-sphere    574/1163(7/28) 576/1167(7/30) 579/1174(7.5/29) 580/1165(7/29) 721/1607(7/48)
set -euo pipefail
here=$(dirname "$0")
hinge=${HINGE:-$here/../../target/release/hinge}
export HINGE=$hinge
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
"$hinge" scenes show drape | sed 's/^cells = \[30, 30\]/cells = [20, 20]/' > "$tmp/drape-20x20.toml"
"$hinge" scenes show drape | sed 's/^cells = \[30, 30\]/cells = [40, 40]/' > "$tmp/drape-40x40.toml"
"$hinge" scenes show anisotropic-drape > "$tmp/anisotropic-drape.toml"
"$hinge" scenes show shell-drop | sed 's/^subdivisions = 4/subdivisions = 3/;
  s/^kind = "plane"/kind = "sphere"\ncenter = [0.0, 0.0, -0.3]\nradius = 0.3/; /^point = /d; /^normal = /d' \
  > "$tmp/shell-on-sphere.toml"
# The edits must have applied (a built-in scene whose lines changed would silently run unedited).
check() { grep -q "$2" "$tmp/$1.toml" || { echo "$1: no \`$2\` (the built-in scene changed)" >&2; exit 1; }; }
check drape-20x20 '^cells = \[20, 20\]'
check drape-40x40 '^cells = \[40, 40\]'
check shell-on-sphere '^subdivisions = 3'
check shell-on-sphere '^radius = 0.3$'
for scene in drape-20x20 drape-40x40 anisotropic-drape shell-on-sphere; do
  printf '%-18s %s\n' "$scene" "$("$here/ensemble.sh" "$tmp/$scene.toml" "$@")"
done
