#!/usr/bin/env python3
"""Closed soft-shell meshes other than the built-in icosphere, for `shell-drop` (issue 14: "soft shells from
other closed meshes will be tried too"). Writes into the directory given (default: here):

- torus.obj: R = 0.35 m, r = 0.15 m (1 m across), 75 × 40 segments, 3 000 vertices, bottom 5 cm above z = 0;
- uvsphere.obj: a latitude-longitude sphere of radius 0.5 m centred at z = 0.55 m, 40 rings × 75 segments,
  2 927 vertices: sliver fans at the poles;
- cylinder.obj: a closed cylinder as CAD exporters tessellate it, r = 0.5 m, 0.4 m tall, 200 segments, one
  ring of side triangles (2 m / 0.4 m: aspect 25) and fan caps (1.8° slivers at the centres), 402 vertices;
- cylinder4.obj: the same with 150 segments and 4 rings, 752 vertices;
- box.obj: a 1 × 1 × 0.5 m box, each face a 20 × 20 grid with random diagonals, 2 402 vertices: 90° creases,
  so rest angles far from flat;
- lumpy.obj: a scanned-looking closed surface, the 4-times subdivided icosahedron (2 562 vertices) with its
  radius modulated by smooth bumps (±8 %) and 1 % noise;
- sd_NAME.toml for each: the built-in `shell-drop` scene (`hinge scenes show shell-drop`) with its generated
  icosphere replaced by the file.

All meshes are numbered at random and every face's corners rotated at random (seeded: the files are the same
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


def cylinder(seg=200, radius=0.5, height=0.4, z0=0.05, rings=1):
    v = []
    for r in range(rings + 1):
        z = z0 + height * r / rings
        for j in range(seg):
            a = 2 * math.pi * j / seg
            v.append((radius * math.cos(a), radius * math.sin(a), z))
    bottom, top = len(v), len(v) + 1
    v += [(0.0, 0.0, z0), (0.0, 0.0, z0 + height)]
    idx = lambda r, j: r * seg + (j % seg)
    f = []
    for r in range(rings):
        for j in range(seg):
            a, b, c, d = idx(r, j), idx(r, j + 1), idx(r + 1, j + 1), idx(r + 1, j)
            f += [(a, b, c), (a, c, d)]
    for j in range(seg):
        f += [(bottom, idx(0, j + 1), idx(0, j)), (top, idx(rings, j), idx(rings, j + 1))]
    return v, f


def box(rng, n=20, size=(1.0, 1.0, 0.5), z0=0.05):
    sx, sy, sz = size
    key, v, f = {}, [], []

    def vid(p):
        k = tuple(round(c, 9) for c in p)
        if k not in key:
            key[k] = len(v)
            v.append(p)
        return key[k]

    # Each face: a corner and two edge vectors u, w with u × w pointing outwards.
    faces = [((-sx / 2, -sy / 2, z0), (0, sy, 0), (sx, 0, 0)),
             ((-sx / 2, -sy / 2, z0 + sz), (sx, 0, 0), (0, sy, 0)),
             ((-sx / 2, -sy / 2, z0), (sx, 0, 0), (0, 0, sz)),
             ((-sx / 2, sy / 2, z0), (0, 0, sz), (sx, 0, 0)),
             ((-sx / 2, -sy / 2, z0), (0, 0, sz), (0, sy, 0)),
             ((sx / 2, -sy / 2, z0), (0, sy, 0), (0, 0, sz))]
    for o, u, w in faces:
        g = [[vid(tuple(o[k] + u[k] * i / n + w[k] * j / n for k in range(3))) for j in range(n + 1)]
             for i in range(n + 1)]
        for i in range(n):
            for j in range(n):
                a, b, c, d = g[i][j], g[i + 1][j], g[i + 1][j + 1], g[i][j + 1]
                f += [(a, b, c), (a, c, d)] if rng.random() < 0.5 else [(a, b, d), (b, c, d)]
    return v, f


def lumpy(rng, subdivisions=4, radius=0.5, z=0.6):
    t = (1 + 5 ** 0.5) / 2
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
         (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2),
         (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11),
         (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    unit = lambda p: tuple(c / math.sqrt(sum(x * x for x in p)) for c in p)
    v = [unit(p) for p in v]
    for _ in range(subdivisions):
        mid = {}

        def m(a, b):
            k = (min(a, b), max(a, b))
            if k not in mid:
                mid[k] = len(v)
                v.append(unit([(v[a][i] + v[b][i]) / 2 for i in range(3)]))
            return mid[k]

        split = []
        for a, b, c in f:
            ab, bc, ca = m(a, b), m(b, c), m(c, a)
            split += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        f = split
    out = []
    for p in v:
        r = radius * (1 + 0.08 * math.sin(3 * p[0] + 1) * math.cos(2 * p[1]) + 0.05 * math.sin(5 * p[2])
                      + 0.01 * (rng.random() - 0.5))
        out.append((p[0] * r, p[1] * r, z + p[2] * r))
    return out, f


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else "."
    os.makedirs(out, exist_ok=True)
    rng = random.Random(3)
    write(os.path.join(out, "torus.obj"), *torus(), rng)
    write(os.path.join(out, "uvsphere.obj"), *uv_sphere(), rng)
    rng = random.Random(7)
    meshes = {"cylinder": cylinder(), "cylinder4": cylinder(seg=150, rings=4), "box": box(rng),
              "lumpy": lumpy(rng)}
    for name, (v, f) in meshes.items():
        write(os.path.join(out, name + ".obj"), v, f, rng)
    hinge = os.environ.get("HINGE", "target/release/hinge")
    scene = subprocess.run([hinge, "scenes", "show", "shell-drop"], check=True, capture_output=True,
                           text=True).stdout
    for name in ("torus", "uvsphere", *meshes):
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
