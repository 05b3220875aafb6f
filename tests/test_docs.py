"""The documentation builds without a single warning and every code block in it runs."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

DOCS = Path(__file__).resolve().parents[1] / "docs"
ROOT = DOCS.parent
PAGES = sorted(DOCS.rglob("*.md"))
EXECUTED = PAGES + [ROOT / "README.md"]

#: A ```python block whose first line is ``# requires: <module>`` runs only where that module imports (the
#: cluster example needs dask-jobqueue and a batch system); one whose first line is ``# file: <name>.py`` is written
#: to that file (a test module a later block runs with pytest); every other block always runs.
REQUIRES = re.compile(r"#\s*requires:\s*([\w.]+)")
FILE = re.compile(r"#\s*file:\s*([\w.]+\.py)\s*$", re.M)
FENCE = re.compile(r"^```python\s*\n(.*?)^```", re.S | re.M)


def python_blocks(page: Path) -> list[str]:
    """The ```python blocks of a Markdown page, in order."""
    return FENCE.findall(page.read_text(encoding="utf-8"))


def test_docs_build_without_warnings(tmp_path: Path) -> None:
    pytest.importorskip("sphinx", reason="install the 'test' extra: pip install -e '.[test]'")
    pytest.importorskip("myst_parser", reason="install the 'test' extra: pip install -e '.[test]'")
    out = tmp_path / "html"
    proc = subprocess.run(
        [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-E", "-q", "-b", "html", str(DOCS), str(out)],
        capture_output=True, text=True, timeout=600,
    )
    assert proc.returncode == 0, f"sphinx-build failed or warned:\n{proc.stdout}\n{proc.stderr}"
    assert (out / "index.html").exists()


@pytest.mark.parametrize("page", [p for p in EXECUTED if python_blocks(p)], ids=lambda p: p.stem)
def test_code_blocks_run(page: Path, tmp_path: Path) -> None:
    """The page's ```python blocks run top to bottom in one fresh interpreter (in a scratch folder)."""
    blocks = []
    for block in python_blocks(page):
        needed, file = REQUIRES.match(block), FILE.match(block)
        if file:
            blocks.append(f"open({file.group(1)!r}, 'w', encoding='utf-8').write({block!r})")
        elif needed:
            blocks.append(f"import importlib.util\nif importlib.util.find_spec({needed.group(1)!r}):\n"
                          + "".join(f"    {line}\n" for line in block.splitlines()))
        else:
            blocks.append(block)
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    # ``python -c``: Dask's spawned workers find no main script to re-run (a user's script has the __main__ guard)
    proc = subprocess.run([sys.executable, "-c", "\n".join(blocks)], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, f"a code block of {page.name} failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-5000:]}"


def test_no_work_log_in_the_docs() -> None:
    """Docs, README and CHANGELOG speak about the package: no work periods, issue numbers or dates."""
    pattern = re.compile(r"\bsession\b|\bissue[ -]?#?\d|\b20\d\d-\d\d-\d\d\b|\b(?:twenty|thirty|forty|fifty)-\w+ "
                         r"(?:session|part)|\bthis work\b|\bfound here\b", re.I)
    files = PAGES + list(DOCS.glob("*.rst")) + [ROOT / "README.md", ROOT / "CHANGELOG.md"]
    hits = [f"{p.relative_to(ROOT)}:{i}: {line.strip()[:80]}" for p in files
            for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1) if pattern.search(line)]
    assert not hits, "work-log wording in the docs:\n" + "\n".join(hits)


#: Files allowed to cite the project's SPEC.md / NOTES (documents outside the
#: repository): none; cite the paper's equations or a docs page instead.
OUTSIDE_REFERENCES_PENDING: set = set()


def test_no_citation_of_documents_outside_the_repository() -> None:
    """Docstrings and docs cite the paper or a docs page, never SPEC.md or the NOTES (not in the repository)."""
    pattern = re.compile(r"\bSPEC\b|SPEC\.md|NOTES")
    files = [p for d in ("diffusion_pr", "gfmd_ref") for p in (ROOT / d).rglob("*.py")]
    files += PAGES + list(DOCS.glob("*.rst")) + [ROOT / "README.md"]
    files += list((ROOT / "notebooks").glob("*.ipynb"))
    offending = sorted(str(p.relative_to(ROOT)) for p in files if pattern.search(p.read_text(encoding="utf-8")))
    new = [f for f in offending if f not in OUTSIDE_REFERENCES_PENDING]
    assert not new, f"cite the paper's equations or a docs page instead of SPEC/NOTES in: {new}"
