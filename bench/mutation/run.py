"""Mutation test (issue 23): apply each hand-made mutation (``mutations.py``) to a throwaway copy of the tree, run
the tests of that part with ``-x -q`` there, and record whether the tests killed it (failed) or it survived.

The working tree is never touched: each mutation gets a fresh copy of the files git knows (tracked and untracked,
not ignored) in a temporary directory, with the built C kernels copied beside (a mutation of a ``.c`` file rebuilds
them there), and the tests run with that copy first on PYTHONPATH.

    PYTHONPATH=. .venv/bin/python bench/mutation/run.py [--only NAME ...] [--jobs N] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(Path(__file__).resolve().parent))

from mutations import MUTATIONS, Mutation  # noqa: E402

KERNEL_GLOBS = (  # the built C kernels
    "train_calib/window/_kernel*.so",
    "train_calib/estimation/_ukf_kernel*.so",
    "train_calib/ingest/_kernel*.so",
)


def copy_tree(dest: Path) -> None:
    """The files git knows under ROOT (not ignored) and the built kernels, copied to ``dest``."""
    listed = subprocess.run(
        ["git", "ls-files", "-co", "--exclude-standard", "-z"], cwd=ROOT, check=True, capture_output=True
    ).stdout.split(b"\0")
    for raw in listed:
        rel = raw.decode()
        src = ROOT / rel
        if not rel or src.is_symlink() or not src.is_file():
            continue  # the .venv link, deleted files
        (dest / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, dest / rel)
    for pattern in KERNEL_GLOBS:
        for so in ROOT.glob(pattern):
            shutil.copy2(so, dest / so.relative_to(ROOT))


def apply(m: Mutation, tree: Path) -> None:
    """Replace the snippet in the copy; ValueError unless it occurs exactly once."""
    path = tree / m.path
    text = path.read_text()
    if text.count(m.old) != 1:
        raise ValueError(f"{m.name}: the snippet occurs {text.count(m.old)} times in {m.path}")
    path.write_text(text.replace(m.old, m.new))


def run_one(m: Mutation, python: str, timeout: float) -> dict:
    """Apply ``m`` to a fresh copy, run its tests; killed when they fail (or the build fails)."""
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix=f"mutant-{m.name}-") as tmp:
        tree = Path(tmp)
        copy_tree(tree)
        apply(m, tree)
        env = dict(os.environ, PYTHONPATH=str(tree), ROS_LOG_DIR=str(tree / "ros_log"))
        if m.path.endswith(".c"):
            build = subprocess.run([python, "setup.py", "build_ext", "--inplace"], cwd=tree, env=env,
                                   capture_output=True, text=True)  # fmt: skip
            if build.returncode != 0:
                return {"name": m.name, "status": "killed", "by": "build", "seconds": time.monotonic() - t0}
        cmd = [python, "-m", "pytest", *m.tests, "-x", "-q", "-p", "no:cacheprovider"]
        try:
            res = subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return {"name": m.name, "status": "killed", "by": "timeout", "seconds": time.monotonic() - t0}
    lines = [line for line in res.stdout.splitlines() if line.strip()]
    failed = [line for line in lines if line.startswith(("FAILED", "ERROR"))]
    return {
        "name": m.name,
        "status": "survived" if res.returncode == 0 else "killed",
        "by": failed[0] if failed else (lines[-1] if lines else ""),
        "seconds": round(time.monotonic() - t0, 1),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--only", nargs="*", help="mutation names (default: all)")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--timeout", type=float, default=900.0, help="s per mutation (a timeout counts as killed)")
    ap.add_argument("--json", type=Path, default=ROOT / "bench" / "out" / "mutation.json")
    args = ap.parse_args()
    chosen = [m for m in MUTATIONS if not args.only or m.name in args.only]
    python = sys.executable
    with ThreadPoolExecutor(args.jobs) as pool:
        results = list(pool.map(lambda m: run_one(m, python, args.timeout), chosen))
    print("| mutation | file | bug | tests | result |\n|---|---|---|---|---|")
    for m, r in zip(chosen, results):
        tests = ", ".join(Path(t).name for t in m.tests)
        if m.survives:
            r["expected"] = "survives"
        result = r["status"] + (" (expected: no bug)" if m.survives else "")
        print(f"| {m.name} | `{m.path}` | {m.description} | {tests} | {result} |", flush=True)
    bugs = [r for m, r in zip(chosen, results) if not m.survives]
    killed = sum(r["status"] == "killed" for r in bugs)
    print(
        f"score: {killed} of {len(bugs)} killed ({killed / max(len(bugs), 1):.0%})"
        + (f"; {len(results) - len(bugs)} mutant(s) that are no bug left out" if len(bugs) < len(results) else "")
    )
    for r in results:
        print(f"  {r['name']}: {r['status']} by {r['by']}")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    doc = {"killed": killed, "total": len(bugs), "not_bugs": len(results) - len(bugs), "results": results}
    args.json.write_text(json.dumps(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
