"""`loopclosure.kernel_cache.drop_stale`: a cached kernel compiled before its callee's
file changed is compiled again, once."""

from __future__ import annotations

import importlib
import os
import sys

from loopclosure.kernel_cache import cached_files, drop_stale, kernels_cold

_CALLEE = "import numba\n\n\n@numba.njit(cache=True)\ndef f(x):\n    return x + {}\n"
_CALLER = ("import numba\n\nfrom kc_callee import f\n\n\n@numba.njit(cache=True)\n"
           "def g(x):\n    return f(x)\n")


def _load():
    for name in ("kc_callee", "kc_caller"):
        sys.modules.pop(name, None)
    importlib.invalidate_caches()
    return importlib.import_module("kc_caller")


def test_a_kernel_cached_before_its_callee_changed_is_compiled_again(tmp_path, monkeypatch):
    callee = tmp_path / "kc_callee.py"
    callee.write_text(_CALLEE.format(1))
    (tmp_path / "kc_caller.py").write_text(_CALLER)
    monkeypatch.syspath_prepend(str(tmp_path))
    try:
        first = _load()
        assert first.g(1) == 2  # compiled with f inlined, written to the cache
        assert drop_stale("kc_caller", ["kc_callee"]) == []  # the callee is older
        cached = cached_files(first.g)
        assert cached
        callee.write_text(_CALLEE.format(20))  # an edit of the callee only ...
        edited = os.stat(callee).st_mtime
        for path in cached:  # ... made after g was compiled
            os.utime(path, (edited - 10.0, edited - 10.0))
        second = _load()
        assert drop_stale("kc_caller", ["kc_callee"]) == ["g"]
        assert kernels_cold([second.g])  # its index emptied: a warm-up would compile it
        assert second.g(1) == 21  # compiled again with the new f
        third = _load()
        assert drop_stale("kc_caller", ["kc_callee"]) == []  # dropped once only
        assert third.g(1) == 21
        assert not kernels_cold([third.g])
    finally:
        for name in ("kc_callee", "kc_caller"):
            sys.modules.pop(name, None)


def test_functions_that_are_not_kernels_of_the_module_are_left_alone(tmp_path, monkeypatch):
    (tmp_path / "kc_plain.py").write_text("from math import hypot\n\n\ndef h(x):\n"
                                          "    return x\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.invalidate_caches()
    try:
        importlib.import_module("kc_plain")
        assert drop_stale("kc_plain", ["kc_plain"]) == []
    finally:
        sys.modules.pop("kc_plain", None)
