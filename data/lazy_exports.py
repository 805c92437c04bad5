"""Front doors that load their names on first use (PEP 562 module ``__getattr__``).

A package whose front door would otherwise import heavy modules (gtsam, scipy,
matplotlib) at every start of the CLI maps each exported name to the module that
defines it; the name is imported the first time it is read and then cached in the
package's namespace, so ``from slam import Mapper`` costs what ``from slam.pipeline
import Mapper`` costs and ``import slam`` alone costs nothing.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from importlib import import_module
from typing import Any

__all__ = ["lazy_exports"]


def lazy_exports(
    package: str, namespace: dict[str, Any], homes: Mapping[str, str]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """``(__getattr__, __dir__)`` for `package` whose `namespace` is its ``globals()``.

    `homes` maps every lazily exported name to the module that defines it.
    """

    def __getattr__(name: str) -> Any:
        home = homes.get(name)
        if home is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(import_module(home), name)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted(set(namespace) | set(homes))

    return __getattr__, __dir__
