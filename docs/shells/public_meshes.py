#!/usr/bin/env python3
"""Public closed meshes as soft shells for `shell-drop` (issue 14: "soft shells from other closed meshes will
be tried too"), as users bring them: scanned or modelled, with their own numbering and sliver triangles.

Usage: `python3 docs/shells/public_meshes.py OUT_DIR MESH.obj [MESH.obj …]`. For each mesh it writes
`OUT_DIR/NAME_1m.obj` (scaled so that its largest bounding-box side is 1 m, centred in x and y, its lowest
point 5 cm above the plane z = 0; faces, numbering and corner order untouched) and two scenes: `sd_NAME.toml`
(the built-in `shell-drop` with its icosphere replaced by the file) and `sdnh_NAME.toml` (the same with
`membrane = "neo-hookean"`). Then: `target/release/hinge run OUT_DIR/sd_NAME.toml --no-frames`.

The meshes measured in docs/newton/README.md ("Public meshes") come from
https://github.com/alecjacobson/common-3d-test-models (`data/spot.obj`, Keenan Crane's cow, 2 930 vertices;
`data/cow.obj`, 2 903), downloaded by hand: nothing here fetches them.
"""
import os
import subprocess
import sys

HINGE = os.path.join(os.path.dirname(__file__), "..", "..", "target", "release", "hinge")


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    out = sys.argv[1]
    os.makedirs(out, exist_ok=True)
    base = subprocess.run([HINGE, "scenes", "show", "shell-drop"], capture_output=True, text=True, check=True).stdout
    for path in sys.argv[2:]:
        name = os.path.splitext(os.path.basename(path))[0]
        with open(path, errors="replace") as f:
            lines = f.read().splitlines()
        vs = [[float(t) for t in line.split()[1:4]] for line in lines if line.startswith("v ")]
        lo = [min(v[i] for v in vs) for i in range(3)]
        hi = [max(v[i] for v in vs) for i in range(3)]
        scale = 1.0 / max(h - l for h, l in zip(hi, lo))
        centre = [(h + l) / 2 for h, l in zip(hi, lo)]
        written = []
        for line in lines:
            if line.startswith("v "):
                p = [float(t) for t in line.split()[1:4]]
                x, y = (p[0] - centre[0]) * scale, (p[1] - centre[1]) * scale
                z = (p[2] - lo[2]) * scale + 0.05
                written.append(f"v {x!r} {y!r} {z!r}")
            else:
                written.append(line)
        with open(os.path.join(out, f"{name}_1m.obj"), "w") as f:
            f.write("\n".join(written) + "\n")
        scene = []
        for line in base.splitlines():
            key = line.split("=")[0].strip()
            if key == "shape":
                scene.append(f'obj = "{name}_1m.obj"')
            elif key in ("subdivisions", "radius", "origin"):
                continue
            elif key == "name":
                scene.append(f'name = "sd-{name}"')
            else:
                scene.append(line)
        text = "\n".join(scene) + "\n"
        with open(os.path.join(out, f"sd_{name}.toml"), "w") as f:
            f.write(text)
        neo = [line + ('\nmembrane = "neo-hookean"' if line.startswith("density") else "") for line in scene]
        with open(os.path.join(out, f"sdnh_{name}.toml"), "w") as f:
            f.write("\n".join(neo) + "\n")
        print(f"{name}: {len(vs)} vertices, scaled by {scale:.4g} → {out}/sd_{name}.toml, sdnh_{name}.toml")


if __name__ == "__main__":
    main()
