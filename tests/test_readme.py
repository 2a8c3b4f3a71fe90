"""README.md's result and benchmark tables are generated from the committed data; they must not drift."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "scripts" / "readme_tables.py"


def test_readme_tables_match_the_committed_data():
    r = subprocess.run([sys.executable, str(SCRIPT), "--check"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


def test_readme_check_notices_a_stale_table(tmp_path, monkeypatch):
    import importlib.util

    spec = importlib.util.spec_from_file_location("readme_tables", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    stale = (ROOT / "README.md").read_text().replace("<!-- begin:fig9 -->\n", "<!-- begin:fig9 -->\n| 99 |\n", 1)
    fake = tmp_path / "README.md"
    fake.write_text(stale)
    monkeypatch.setattr(mod, "README", fake)
    assert mod.main(["--check"]) == 1
    assert mod.main([]) == 0 and fake.read_text() == (ROOT / "README.md").read_text()
