#!/usr/bin/env python3
"""Every value of every built-in scene replaced by extreme ones: the run must end cleanly.

For each built-in scene (`hinge scenes`), each `key = value` line of `hinge scenes show NAME` is replaced by
0, -1, 1e-300, 1e300, -1e300, nan, inf, -inf, 1e20, 2**32, 0.5, a string, an empty array and a boolean
(array values: each element in turn by the first ten of those), or deleted; each variant runs
`hinge run FILE --frames 2 --no-frames --threads 1` at a small resolution with a 60 s limit. A run is
flagged when it panics, exits with another code than 0/1/2, takes the whole 60 s, fails with more than one
line (warnings aside) or succeeds with NaN or infinity in its `summary.json`.

    python3 docs/robustness/scene_sweep.py [HINGE] [--jobs N]

HINGE defaults to target/release/hinge. Prints the flagged runs and a count; exits 1 if any.
"""
import concurrent.futures as cf
import os
import re
import subprocess
import sys
import tempfile

HINGE = next((a for a in sys.argv[1:] if not a.startswith("--") and not a.isdigit()), "target/release/hinge")
JOBS = int(sys.argv[sys.argv.index("--jobs") + 1]) if "--jobs" in sys.argv else 2
SCENES = {"drape": "4", "shell-drop": "1", "beam3": "1", "anisotropic-drape": "4", "twist": None, "crease": None}
VALUES = ["0", "-1", "1e-300", "1e300", "-1e300", "nan", "inf", "-inf", "1e20", "4294967296", "0.5", '"bogus"',
          "[]", "true"]
LINE = re.compile(r"^(\s*[A-Za-z_][\w-]*\s*=\s*)(.*?)(\s*(#.*)?)$")


def variants(text):
    lines = text.split("\n")
    for i, line in enumerate(lines):
        m = LINE.match(line)
        if not m:
            continue
        value = m.group(2)
        if value.startswith("["):
            inner = value.strip("[]")
            parts = [p.strip() for p in inner.split(",")] if inner.strip() else []
            news = []
            for k in range(len(parts)):
                for x in VALUES[:10]:
                    q = parts[:]
                    q[k] = x
                    news.append("[" + ", ".join(q) + "]")
            news += ["[]", '"bogus"']
        else:
            news = VALUES
        for x in news + [None]:
            edited = lines[:]
            edited[i] = "" if x is None else m.group(1) + x
            yield line.strip(), "<deleted>" if x is None else x, "\n".join(edited)


def run(job):
    scene, line, value, text, work = job
    fd, path = tempfile.mkstemp(suffix=".toml", dir=work)
    with os.fdopen(fd, "w") as f:
        f.write(text)
    out = path[:-5]
    args = [HINGE, "run", path, "--frames", "2", "--no-frames", "--threads", "1", "--out", out]
    if SCENES[scene]:
        args += ["--resolution", SCENES[scene]]
    try:
        o = subprocess.run(args, capture_output=True, text=True, timeout=60)
    except subprocess.TimeoutExpired:
        return scene, line, value, "timeout", ""
    err = o.stderr.strip()
    bad = []
    if "panicked" in err or o.returncode not in (0, 1, 2):
        bad.append(f"exit code {o.returncode}")
    if o.returncode != 0:
        lines = [q for q in err.split("\n") if q.strip() and "warning" not in q]
        if len(lines) != 1:
            bad.append(f"{len(lines)} error lines")
    else:
        try:
            with open(os.path.join(out, "summary.json")) as f:
                if re.search(r"\bNaN\b|\bnan\b|Infinity|\binf\b", f.read()):
                    bad.append("NaN or infinity in summary.json")
        except OSError:
            bad.append("no summary.json")
    return scene, line, value, ", ".join(bad), err[-300:]


def main():
    with tempfile.TemporaryDirectory() as work:
        jobs = []
        for scene in SCENES:
            text = subprocess.run([HINGE, "scenes", "show", scene], capture_output=True, text=True,
                                  check=True).stdout
            jobs += [(scene, line, value, edited, work) for line, value, edited in variants(text)]
        with cf.ThreadPoolExecutor(JOBS) as ex:
            results = list(ex.map(run, jobs))
    flagged = [r for r in results if r[3]]
    for scene, line, value, why, err in flagged:
        print(f"{scene} | {line} -> {value} | {why} | {err.replace(chr(10), ' // ')}")
    print(f"{len(results)} runs, {len(flagged)} flagged")
    sys.exit(1 if flagged else 0)


if __name__ == "__main__":
    main()
