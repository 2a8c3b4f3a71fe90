"""Record the time of a fresh-clone ``make test`` from its log, for README's timing line (never typed by hand).

    ../shared/bin/fresh-check test 2>&1 | tee /tmp/fresh.log
    python scripts/fresh_check_times.py /tmp/fresh.log      # writes benchmarks/fresh_check.json
    python scripts/fresh_check_times.py /tmp/fresh.log /tmp/fresh-book.log COMMIT   # and a `fresh-check book` run

Reads from the log: the total (``fresh-check test: passed in N s``), each chapter's execution time as MyST-NB logs
it (``chapters/05_rmse_vs_snr.md: Executed notebook in N seconds``), pytest's summaries (``N passed ... in N s``) and
its slowest test phases (``--durations``; the ``SLOWEST`` longest of both runs):
Where a log holds more than one pytest run (``make test`` prints the log of the tests that need no book, then that of
those marked "book"), the counts are summed and each run's time kept (``pytest_runs_s``, in that order).
Records them with the commit and the machine; ``scripts/readme_tables.py`` renders README's timing paragraph from
the file.  Exit 2 with one line if the log lacks any of them.
"""

from __future__ import annotations

import json
import os
import platform
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "benchmarks" / "fresh_check.json"
#: the slowest test phases recorded (pytest's ``--durations``, both runs of ``make test`` together)
SLOWEST = 20


def parse(log: str) -> dict:
    total = re.findall(r"fresh-check test: passed in (\d+)s", log)
    chapters = {m.group(1): float(m.group(2))
                for m in re.finditer(r"chapters/(\w+)\.md: Executed notebook in ([\d.]+) seconds", log)}
    summary = re.findall(r"=+ (\d+) passed(?:, (\d+) skipped)?[^=]* in ([\d.]+)s", log)
    if not total or not chapters or not summary:
        raise ValueError("the log lacks the fresh-check total, the chapters' execution times or pytest's summary")
    runs = [float(secs) for _, _, secs in summary]
    slowest = sorted(((float(secs), phase, test) for secs, phase, test in
                      re.findall(r"^\s*([\d.]+)s (call|setup|teardown)\s+(\S+)", log, re.M)), reverse=True)
    rec = {"make_test_s": int(total[-1]), "chapters_s": chapters, "pytest_s": sum(runs),
           "tests_passed": sum(int(p) for p, _, _ in summary), "tests_skipped": sum(int(s or 0) for _, s, _ in summary),
           "slowest_tests": [list(t) for t in slowest[:SLOWEST]]}
    return {**rec, "pytest_runs_s": runs} if len(runs) > 1 else rec


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) not in (1, 3):
        print("usage: fresh_check_times.py LOG [BOOK_LOG BOOK_COMMIT]", file=sys.stderr)
        return 2
    try:
        rec = parse(Path(argv[0]).read_text(errors="replace"))
        if len(argv) == 3:
            book = re.findall(r"fresh-check book: passed in (\d+)s", Path(argv[1]).read_text(errors="replace"))
            if not book:
                raise ValueError(f"{argv[1]} lacks the line 'fresh-check book: passed in N s'")
            rec.update(make_book_s=int(book[-1]), make_book_commit=argv[2])
    except (OSError, ValueError) as exc:
        print(f"fresh_check_times: {exc}", file=sys.stderr)
        return 2
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                            text=True).stdout.strip()
    rec = {"commit": commit, "machine": {"cpus": os.cpu_count(), "platform": platform.platform(terse=True)}, **rec}
    OUT.write_text(json.dumps(rec, indent=1, sort_keys=True) + "\n")
    print(f"wrote {OUT.relative_to(ROOT)}: make test {rec['make_test_s']} s at {commit}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
