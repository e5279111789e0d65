"""Fail when python/Cargo.lock pins another version of a crate than Cargo.lock does.

`.ci/run` builds the Python package into the main workspace's target directory so that it reuses the
dependencies the workspace build compiled; that only works when both lock files pin the same versions.
Fix a mismatch with `cargo update -p NAME --precise VERSION` inside python/.
"""

import re
import sys

# Cargo.lock is written by cargo in a fixed layout: `name = "..."` followed by `version = "..."`.
# (A regular expression rather than tomllib, which needs Python 3.11.)
ENTRY = re.compile(r'^name = "([^"]+)"\nversion = "([^"]+)"$', re.MULTILINE)


def versions(path):
    with open(path, encoding="utf-8") as f:
        text = f.read()
    out = {}
    for name, version in ENTRY.findall(text):
        out.setdefault(name, set()).add(version)
    return out


main = versions("Cargo.lock")
python = versions("python/Cargo.lock")
bad = [
    f"{name}: python/Cargo.lock {sorted(v)} vs Cargo.lock {sorted(main[name])}"
    for name, v in sorted(python.items())
    if name in main and main[name] != v
]
if bad:
    print("python/Cargo.lock and Cargo.lock disagree: " + "; ".join(bad), file=sys.stderr)
    sys.exit(1)
