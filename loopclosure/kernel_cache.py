"""numba's on-disk cache (``cache=True``) of kernels that call kernels of other modules.

numba keys a cached kernel on its own source file only (modification time and size),
yet compiles the kernels it calls from other modules into it: after an edit of a
callee's file, the caller's cache still loads the old callee's machine code (a
limitation numba documents).  The compiled ICP's kernels call across modules
(`loopclosure.icp_kernel` and `loopclosure.grid_overlap` into
`loopclosure.grid_nearest`, all of them into `loopclosure.grid_target`), so each
calling module runs `drop_stale` when imported: a kernel whose cached machine code is
older than a callee's source file is compiled again on its next call.  Nothing changes
while the sources do not; a fresh install has no cache to drop.

`kernel_callees` finds, from the kernels' code, the modules a module's kernels compile
in (kernels called and constants read, through each other); `undeclared_callees`, those
its `drop_stale` call does not name, so that a test keeps every calling module covered.
"""

from __future__ import annotations

import ast
import os
import sys
import sysconfig
import types
from collections.abc import Sequence

_DECLARED: dict[str, tuple[str, ...]] = {}  # module -> the callees its drop_stale named


def cached_files(kernel: object) -> list[str] | None:
    """Paths of the machine-code files that numba's cache index of `kernel` (a
    dispatcher) refers to now (none when the index is missing or stale for the
    kernel's own file); None without an on-disk cache (or a numba that keeps it
    otherwise)."""
    try:
        files = kernel._cache._cache_file  # type: ignore[attr-defined]
        return [files._data_path(name) for name in files._load_index().values()]
    except AttributeError:
        return None


def drop_stale(module: str, callees: Sequence[str]) -> list[str]:
    """Empty numba's cache index of every kernel defined in `module` (an imported
    module's name) whose cached machine code was written before the last change of the
    source file of one of `callees` (the imported modules whose kernels `module`'s
    kernels call, directly or through each other), so that its next call compiles it
    again.  Returns the names of the kernels dropped, in definition order."""
    _DECLARED[module] = tuple(callees)
    newest = max(os.stat(sys.modules[name].__file__).st_mtime for name in callees)
    dropped = []
    for name, kernel in vars(sys.modules[module]).items():
        py_func = getattr(kernel, "py_func", None)
        if getattr(py_func, "__module__", None) != module:
            continue  # not a kernel, or one imported from elsewhere
        paths = cached_files(kernel)
        if paths and any(os.path.exists(p) and os.stat(p).st_mtime < newest for p in paths):
            try:
                kernel._cache.flush()  # type: ignore[attr-defined]
            except OSError:
                continue  # a read-only cache (an installed copy, whose sources stay put)
            dropped.append(name)
    return dropped


def kernels_cold(kernels: Sequence[object]) -> bool:
    """True when a kernel of `kernels` (dispatchers with ``cache=True``) has no usable
    machine code on disk: its index missing, stale for its own file, emptied by
    `drop_stale`, or naming a file that is gone; False as well for a numba that keeps
    its cache otherwise (no way to tell)."""
    files = [cached_files(k) for k in kernels]
    if any(f is None for f in files):
        return False
    return not all(f and all(os.path.exists(p) for p in f) for f in files)


def _kernels(module: types.ModuleType) -> list[object]:
    """The numba dispatchers defined in `module` (not those it imports)."""
    return [k for k in vars(module).values()
            if getattr(getattr(k, "py_func", None), "__module__", None) == module.__name__]


def _global_names(code: types.CodeType) -> set[str]:
    """Names a function's code (its nested functions' included) looks up as globals or
    attributes."""
    names = set(code.co_names)
    for const in code.co_consts:
        if isinstance(const, types.CodeType):
            names |= _global_names(const)
    return names


def _imported_from(module: types.ModuleType, name: str) -> str | None:
    """The module a ``from X import name`` of `module`'s source names (relative imports
    resolved), or None when `module` binds `name` otherwise."""
    path = getattr(module, "__file__", None)
    if not path or not path.endswith(".py"):
        return None
    with open(path, encoding="utf-8") as source:
        tree = ast.parse(source.read())
    package = module.__name__
    if not path.endswith("__init__.py"):
        package = package.rpartition(".")[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and any(
                (alias.asname or alias.name) == name for alias in node.names):
            if node.level == 0:
                return node.module
            base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
            return f"{base}.{node.module}" if node.module else base
    return None


def _is_own(module: types.ModuleType | None) -> bool:
    """True for a module with a source file outside the interpreter's standard library
    and installed packages: the project's own (wherever its checkout sits)."""
    path = getattr(module, "__file__", None)
    if module is None or not path:
        return False
    paths = sysconfig.get_paths()
    installed = {os.path.realpath(paths[key]) for key in ("stdlib", "platstdlib", "purelib",
                                                          "platlib")}
    real = os.path.realpath(path)
    return not any(real.startswith(folder + os.sep) for folder in installed)


def _homes(module: types.ModuleType) -> set[str]:
    """The other own modules whose kernels or values `module`'s kernels refer to by name
    (a kernel by the module that defines it, a value by the module it is imported from,
    followed through re-exports, a module by itself)."""
    homes = set()
    for kernel in _kernels(module):
        for name in _global_names(kernel.py_func.__code__):  # type: ignore[attr-defined]
            if name not in vars(module):
                continue
            value = vars(module)[name]
            py_func = getattr(value, "py_func", None)
            if py_func is not None:
                home = py_func.__module__
            elif isinstance(value, types.ModuleType):
                home = value.__name__
            else:
                home, seen = _imported_from(module, name), {module.__name__}
                while home and home not in seen and home in sys.modules:
                    seen.add(home)
                    further = _imported_from(sys.modules[home], name)
                    if further is None:
                        break
                    home = further
            if home and home != module.__name__ and _is_own(sys.modules.get(home)):
                homes.add(home)
    return homes


def kernel_callees(module: str) -> list[str]:
    """The own modules (not installed packages) whose source the kernels of `module` (an
    imported module's name) compile in: those whose kernels they call or whose values
    (compile-time constants) they read, directly or through each other's kernels;
    sorted.  These are the `callees` its `drop_stale` call must name."""
    found: set[str] = set()
    todo = [module]
    while todo:
        for home in _homes(sys.modules[todo.pop()]):
            if home not in found and home != module:
                found.add(home)
                todo.append(home)
    return sorted(found)


def undeclared_callees(module: str) -> list[str]:
    """`kernel_callees` of `module` that no `drop_stale` call of it has named (all of
    them when it made none): a non-empty list means an edit of one of them would leave
    `module`'s cached kernels running the old code."""
    declared = set(_DECLARED.get(module, ()))
    return [name for name in kernel_callees(module) if name not in declared]


__all__ = ["cached_files", "drop_stale", "kernel_callees", "kernels_cold",
           "undeclared_callees"]
