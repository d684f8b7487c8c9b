"""The mutation-testing record (docs/testing.md) agrees with its data.

``docs/mutation/nmpc-verdicts.json.gz`` holds the verdict of every ``nmpc/`` mutant that
docs/testing.md counts; ``tools/mutation_report.py --verdicts`` makes the table from it.
Truth: the table as published in docs/testing.md (its last ``nmpc/`` table), and the
kill-rate definition (killed by the run or by a subset run, over all counted mutants).
"""

from __future__ import annotations

import gzip
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
VERDICTS = ROOT / "docs" / "mutation" / "nmpc-verdicts.json.gz"


def test_the_published_nmpc_table_is_the_one_its_verdicts_give():
    out = subprocess.run(
        [sys.executable, str(ROOT / "tools" / "mutation_report.py"), "--verdicts", str(VERDICTS)],
        capture_output=True, text=True, check=True, timeout=60,
    ).stdout.strip()  # fmt: skip
    doc = (ROOT / "docs" / "testing.md").read_text()
    assert out in doc  # the whole table, row by row
    verdicts = json.loads(gzip.decompress(VERDICTS.read_bytes()))
    killed = sum(s in {"killed", "timeout", "segfault", "killed by a subset run"}
                 for s in verdicts.values())  # fmt: skip
    total = out.splitlines()[-1]
    assert f"| {len(verdicts)} |" in total
    assert f"| {100 * killed / len(verdicts):.1f} % |" in total
