"""`loopclosure.kernel_cache.kernel_callees`: the modules a module's kernels compile in,
and every kernel module of the project naming them in its `drop_stale` call."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import pytest

from loopclosure.kernel_cache import drop_stale, kernel_callees, undeclared_callees

_FILES = {
    # a kernel and a constant of its own
    "kcc_leaf.py": "import numba\n\nSCALE = 3\n\n\n@numba.njit(cache=True)\n"
                   "def f(x):\n    return x + 1\n",
    # a kernel calling the leaf's kernel
    "kcc_mid.py": "import numba\n\nfrom kcc_leaf import f\n\n\n@numba.njit(cache=True)\n"
                  "def m(x):\n    return f(x) * 2\n",
    # the leaf's constant re-exported, no kernel
    "kcc_reexport.py": "from kcc_leaf import SCALE\n",
    # a module whose plain function (not a kernel) the top module calls
    "kcc_other.py": "def helper():\n    return 1\n",
    # the top: kernel -> mid's kernel (-> leaf's kernel), a re-exported constant, the
    # standard library; a plain function that calls another own module
    "kcc_top.py": "import math\n\nimport numba\n\nfrom kcc_mid import m\n"
                  "from kcc_other import helper\nfrom kcc_reexport import SCALE\n\n\n"
                  "@numba.njit(cache=True)\n"
                  "def t(x):\n    return m(x) * SCALE + math.sqrt(x)\n\n\n"
                  "def plain():\n    return helper()\n",
    # a package whose kernel calls its sibling's through a relative import
    "kcc_pkg/__init__.py": "",
    "kcc_pkg/b.py": "import numba\n\n\n@numba.njit(cache=True)\ndef g(x):\n    return x - 1\n",
    "kcc_pkg/a.py": "import numba\n\nfrom .b import g\n\n\n@numba.njit(cache=True)\n"
                    "def h(x):\n    return g(x)\n",
}


@pytest.fixture
def fixture_modules(tmp_path, monkeypatch):
    """`_FILES` written to a folder on the import path; forgotten afterwards."""
    for name, text in _FILES.items():
        path = tmp_path / name
        path.parent.mkdir(exist_ok=True)
        path.write_text(text)
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.invalidate_caches()
    yield
    for name in [n for n in sys.modules if n.startswith("kcc_")]:
        sys.modules.pop(name)


def test_callees_are_found_through_kernels_and_constants(fixture_modules):
    importlib.import_module("kcc_top")
    # mid by its kernel, leaf through mid's kernel and as the home of SCALE (the
    # re-export followed); not kcc_other (a plain function calls it), not math.
    assert kernel_callees("kcc_top") == ["kcc_leaf", "kcc_mid"]
    assert kernel_callees("kcc_mid") == ["kcc_leaf"]
    assert kernel_callees("kcc_leaf") == []
    importlib.import_module("kcc_pkg.a")
    assert kernel_callees("kcc_pkg.a") == ["kcc_pkg.b"]


def test_undeclared_callees_are_those_no_drop_stale_call_named(fixture_modules):
    importlib.import_module("kcc_top")
    assert undeclared_callees("kcc_top") == ["kcc_leaf", "kcc_mid"]
    drop_stale("kcc_top", ["kcc_mid"])  # the direct callee only
    assert undeclared_callees("kcc_top") == ["kcc_leaf"]
    drop_stale("kcc_top", ["kcc_mid", "kcc_leaf"])
    assert undeclared_callees("kcc_top") == []


def _kernel_modules() -> list[str]:
    """Every module of `loopclosure` and `slam` whose source defines a numba kernel."""
    root = Path(__file__).resolve().parents[1]
    names = []
    for package in ("loopclosure", "slam"):
        for path in sorted((root / package).rglob("*.py")):
            if "njit" in path.read_text(encoding="utf-8"):  # numba.njit or njit
                parts = path.relative_to(root).with_suffix("").parts
                names.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return names


def test_every_kernel_module_drops_its_stale_kernels_for_all_its_callees():
    modules = _kernel_modules()
    assert "loopclosure.icp_kernel" in modules and "slam.selected_inverse_kernel" in modules
    missing = {}
    for name in modules:
        importlib.import_module(name)  # a calling module runs drop_stale when imported
        if undeclared_callees(name):
            missing[name] = undeclared_callees(name)
    assert missing == {}
