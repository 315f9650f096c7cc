"""scripts/fresh-check reads the README's set-up commands and pyproject's lower bounds itself: both
parse, and say what the README and pyproject say."""

from __future__ import annotations

import importlib.machinery
import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _script():
    loader = importlib.machinery.SourceFileLoader("fresh_check", str(ROOT / "scripts" / "fresh-check"))
    module = importlib.util.module_from_spec(importlib.util.spec_from_loader("fresh_check", loader))
    loader.exec_module(module)
    return module


def test_the_readme_commands_are_the_two_set_up_blocks():
    main_job, tests = _script().readme_commands(ROOT / "README.md")
    assert main_job == "pip install -e . && sbcal run"
    assert tests == 'pip install -e ".[test]" && python -m pytest'


def test_a_readme_without_the_two_blocks_is_refused(tmp_path):
    bad = tmp_path / "README.md"
    bad.write_text("# x\n\n## Set up\n\n```bash\npip install -e .\n```\n\n## Next\n")
    with pytest.raises(SystemExit, match="two bash blocks"):
        _script().readme_commands(bad)


def test_lowest_pins_every_lower_bound_to_its_release_line():
    pins = _script().lowest_constraints(ROOT / "pyproject.toml")
    assert "numpy==2.0.*" in pins and "pytest==7.*" in pins and "distributed==2024.1.*" in pins
    names = [p.split("==")[0].lower() for p in pins]
    assert len(names) == len(set(names)) and {"scipy", "pandas", "arviz", "emcee"} <= set(names)
