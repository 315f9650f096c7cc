"""The library API: every name ``import sbcal`` exports resolves to the one object its module defines,
is documented, and is listed in docs/api.md; importing the package stays light."""

import re
import subprocess
import sys
from pathlib import Path

import sbcal

API = Path(__file__).resolve().parents[1] / "docs" / "api.md"


def test_every_exported_name_resolves_to_its_module_object_and_has_a_docstring():
    for name in sbcal.__all__:
        obj = getattr(sbcal, name)
        module = getattr(obj, "__module__", None)
        if callable(obj) and module and module.startswith("sbcal."):
            assert getattr(sys.modules[module], name) is obj, name
            assert (obj.__doc__ or "").strip(), f"{name}: no docstring"


def test_docs_api_lists_exactly_the_exported_names():
    listed = set(re.findall(r"^\| `(\w+)` \| `sbcal\.", API.read_text(encoding="utf-8"), flags=re.M))
    assert listed == set(sbcal.__all__) - {"__version__"}


def test_import_sbcal_does_not_load_the_sampler_or_arviz():
    code = "import sys, sbcal; print(sorted(m for m in ('arviz', 'emcee', 'sbcal.inference.sampler') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "[]", out


def test_an_unknown_name_is_an_attribute_error():
    try:
        sbcal.no_such_name  # noqa: B018
    except AttributeError as e:
        assert "no_such_name" in str(e)
    else:
        raise AssertionError("sbcal.no_such_name resolved")


SUBPACKAGES = ("data", "model", "inference", "diagnosis", "design", "simulate", "report")


def test_each_subpackage_exports_its_interface_and_shadows_no_submodule():
    """A subpackage's names are the objects its modules define (the same as ``sbcal``'s where both
    export one), and none is named as one of its submodules (which would shadow it once imported)."""
    import importlib
    import pkgutil

    for sub in SUBPACKAGES:
        pkg = importlib.import_module(f"sbcal.{sub}")
        modules = {m.name for m in pkgutil.iter_modules(pkg.__path__)}
        assert pkg.__all__ and not set(pkg.__all__) & modules, sub
        for name in pkg.__all__:
            obj = getattr(pkg, name)
            if name in sbcal.__all__:
                assert getattr(sbcal, name) is obj, (sub, name)
            if callable(obj) and getattr(obj, "__module__", "").startswith("sbcal."):
                assert (obj.__doc__ or "").strip(), f"sbcal.{sub}.{name}: no docstring"


def test_docs_api_names_every_subpackage():
    text = API.read_text(encoding="utf-8")
    for sub in SUBPACKAGES:
        assert f"`sbcal.{sub}`" in text, sub
