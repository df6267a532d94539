"""Run every benchmark in bench/ one after the other (``make bench``); each prints its own table.

    .venv/bin/python bench/run_all.py [--quick]

``--quick`` passes ``--quick`` to every benchmark that has it (a smoke run: noisier numbers). The time each
benchmark took is printed after it and again at the end, so a benchmark that grows is seen at once.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def has_quick(script: Path) -> bool:
    return '"--quick"' in script.read_text()


def main(argv: list[str] | None = None) -> int:
    quick = "--quick" in (argv if argv is not None else sys.argv[1:])
    failed, took = [], {}
    began = time.monotonic()
    for script in sorted(HERE.glob("*.py")):
        if script.name in ("run_all.py", "__init__.py") or script.name.startswith("_"):
            continue
        print(f"\n=== {script.name} ===", flush=True)
        args = [sys.executable, str(script)] + (["--quick"] if quick and has_quick(script) else [])
        start = time.monotonic()
        if subprocess.run(args, cwd=HERE.parent).returncode != 0:
            failed.append(script.name)
        took[script.name] = time.monotonic() - start
        print(f"=== {script.name}: {took[script.name]:.0f} s ===", flush=True)
    print("\n" + ", ".join(f"{name} {seconds:.0f} s" for name, seconds in took.items()))
    print(f"all benchmarks: {time.monotonic() - began:.0f} s")
    if failed:
        print(f"failed: {', '.join(failed)}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
