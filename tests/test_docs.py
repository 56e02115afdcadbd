"""The documentation: the docs site builds with ``--strict``, the README stays short and its links resolve, the
configuration reference is what the code says."""

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
REFERENCE = ROOT / "docs" / "reference" / "configuration.md"


# ---- the site ---------------------------------------------------------------------------------------------
def test_docs_site_builds_strict(tmp_path):
    """Every page in the nav, every link and anchor resolved (mkdocs.yml's validation: warn, and --strict)."""
    missing = [m for m in ("mkdocs", "material") if importlib.util.find_spec(m) is None]
    if missing:
        pytest.skip(f"{' and '.join(missing)} not installed (the dev extra: pip install -e '.[dev]')")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}  # mkdocs-material's banner about MkDocs 2.0
    site = tmp_path / "site"
    command = [sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file", str(ROOT / "mkdocs.yml"),
               "--site-dir", str(site)]  # fmt: skip
    r = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, f"mkdocs build --strict failed:\n{r.stdout}\n{r.stderr}"
    assert (site / "index.html").is_file() and (site / "reference" / "configuration" / "index.html").is_file()


# ---- the README -------------------------------------------------------------------------------------------
def test_readme_is_short():
    n = len(README.read_text(encoding="utf-8").splitlines())
    assert n <= 250, f"README.md has {n} lines (at most 250): move details into docs/"


def test_readme_keeps_the_two_commands():
    text = README.read_text(encoding="utf-8")
    assert "make demo" in text and "make test" in text


_LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")


def test_readme_relative_links_exist():
    broken = []
    for target in _LINK.findall(README.read_text(encoding="utf-8")):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):  # http:, mailto:, an anchor
            continue
        path = target.split("#", 1)[0]
        if not (ROOT / path).exists():
            broken.append(target)
    assert not broken, f"README.md links to files that do not exist: {broken}"


# ---- the configuration reference ----------------------------------------------------------------------------
def test_configuration_reference_is_current():
    """docs/reference/configuration.md is written from the stages' Configs; a changed field doc, type or default
    makes it stale."""
    from mirage2matter.commands.reference import REGENERATE, configuration_reference

    now = configuration_reference()
    committed = REFERENCE.read_text(encoding="utf-8") if REFERENCE.is_file() else ""
    if committed != now:
        old, new = committed.splitlines(), now.splitlines()
        i = next((k for k, (a, b) in enumerate(zip(old, new, strict=False)) if a != b), min(len(old), len(new)))
        first = f"line {i + 1}:\n  committed: {old[i] if i < len(old) else '(end)'}\n  now:       " \
                f"{new[i] if i < len(new) else '(end)'}"  # fmt: skip
        pytest.fail(f"docs/reference/configuration.md differs from the stages' Configs; regenerate it with\n"
                    f"  {REGENERATE}\nfirst difference at {first}")  # fmt: skip


def test_configuration_reference_covers_every_stage():
    from mirage2matter.commands.reference import configuration_reference
    from mirage2matter.stages import STAGES

    text = configuration_reference()
    for s in STAGES:
        assert f"## {s.name}: `m2m {s.command}`" in text
    assert "| `minutes` | `--minutes` | float in `[0, 100000]` |" in text  # scene.minutes: setting, flag, type, range
    assert "| `matting.iterations` | `--matting.iterations` | int in `[1, 1000000]` |" in text  # nested
