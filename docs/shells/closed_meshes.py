#!/usr/bin/env python3
"""Closed soft-shell meshes other than the built-in icosphere, for `shell-drop` (issue 14: "soft shells from
other closed meshes will be tried too"). Writes into the directory given (default: here):

- torus.obj: R = 0.35 m, r = 0.15 m (1 m across), 75 × 40 segments, 3 000 vertices, bottom 5 cm above z = 0;
- uvsphere.obj: a latitude-longitude sphere of radius 0.5 m centred at z = 0.55 m, 40 rings × 75 segments,
  2 927 vertices: sliver fans at the poles;
- sd_torus.toml, sd_uvsphere.toml: the built-in `shell-drop` scene (`hinge scenes show shell-drop`) with its
  generated icosphere replaced by the file.

Both meshes are numbered at random and every face's corners rotated at random (seeded: the files are the same
on every run). Then: `target/release/hinge run DIR/sd_torus.toml --no-frames`.
"""
import math
import os
import random
import subprocess
import sys


def write(path, vertices, faces, rng):
    perm = list(range(len(vertices)))
    rng.shuffle(perm)
    new = [0] * len(vertices)
    for n, old in enumerate(perm):
        new[old] = n
    with open(path, "w") as f:
        for old in perm:
            f.write("v %.9f %.9f %.9f\n" % vertices[old])
        for t in faces:
            t = [new[i] + 1 for i in t]
            r = rng.randrange(3)
            t = t[r:] + t[:r]
            f.write("f %d %d %d\n" % tuple(t))


def torus(n=75, m=40, big=0.35, small=0.15, z=0.2):
    v = []
    for i in range(n):
        for j in range(m):
            u, w = 2 * math.pi * i / n, 2 * math.pi * j / m
            rho = big + small * math.cos(w)
            v.append((rho * math.cos(u), rho * math.sin(u), z + small * math.sin(w)))
    idx = lambda i, j: (i % n) * m + (j % m)
    f = []
    for i in range(n):
        for j in range(m):
            a, b, c, d = idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1)
            f += [(a, b, c), (a, c, d)]
    return v, f


def uv_sphere(rings=40, segments=75, radius=0.5, z=0.55):
    v = [(0.0, 0.0, z + radius)]
    for i in range(1, rings):
        th = math.pi * i / rings
        for j in range(segments):
            ph = 2 * math.pi * j / segments
            v.append((radius * math.sin(th) * math.cos(ph), radius * math.sin(th) * math.sin(ph),
                      z + radius * math.cos(th)))
    v.append((0.0, 0.0, z - radius))
    south = len(v) - 1
    ring = lambda i, j: 1 + (i - 1) * segments + (j % segments)
    f = [(0, ring(1, j), ring(1, j + 1)) for j in range(segments)]
    for i in range(1, rings - 1):
        for j in range(segments):
            a, b, c, d = ring(i, j), ring(i + 1, j), ring(i + 1, j + 1), ring(i, j + 1)
            f += [(a, b, c), (a, c, d)]
    f += [(south, ring(rings - 1, j + 1), ring(rings - 1, j)) for j in range(segments)]
    return v, f


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else "."
    os.makedirs(out, exist_ok=True)
    rng = random.Random(3)
    write(os.path.join(out, "torus.obj"), *torus(), rng)
    write(os.path.join(out, "uvsphere.obj"), *uv_sphere(), rng)
    hinge = os.environ.get("HINGE", "target/release/hinge")
    scene = subprocess.run([hinge, "scenes", "show", "shell-drop"], check=True, capture_output=True,
                           text=True).stdout
    for name in ("torus", "uvsphere"):
        lines = []
        for line in scene.splitlines():
            key = line.split("=")[0].strip()
            if key == "shape":
                lines.append(f'obj = "{name}.obj"')
            elif key not in ("subdivisions", "radius", "origin"):
                lines.append(line)
        with open(os.path.join(out, f"sd_{name}.toml"), "w") as f:
            f.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
