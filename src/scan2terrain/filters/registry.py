"""The filters a user can choose (``--filter``, ``filter.kind``), declared once.

Each entry names the function that runs the filter (``module:function`` in this package,
imported when the filter first runs, so that ``--help`` loads no numpy), whether it takes a
window side (``size``; else it is 3x3 and takes the ``fallback`` for the cells it does not keep:
'majority' for occupancy labels, 'median' for ordered greys), and a one-line help.
``config.FILTERS`` (with 'none'), the CLI's ``choices=`` and help, and the grid steps all read
this table: adding a filter is one function in this package and one line here.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal, TypeVar

from scan2terrain.config import FILTERS as FILTER_KINDS
from scan2terrain.config import FilterKind

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

    ScalarT = TypeVar("ScalarT", bound=np.generic)

Fallback = Literal["majority", "median"]


@dataclass(frozen=True)
class Filter:
    function: str  #: "module:function" in scan2terrain.filters
    window: bool  #: takes ``size`` (an odd window side); else 3x3 with a ``fallback``
    help: str

    def run(self, a: NDArray[ScalarT], size: int, fallback: Fallback) -> NDArray[ScalarT]:
        module, name = self.function.split(":")
        fn = getattr(importlib.import_module(f"scan2terrain.filters.{module}"), name)
        out: NDArray[ScalarT] = fn(a, size=size) if self.window else fn(a, fallback=fallback)
        return out


FILTERS: dict[FilterKind, Filter] = {
    "median": Filter("median:median_filter", True, "the plain median of the window"),
    "majority": Filter("majority:majority_filter", True, "the most frequent value of the window"),
    "paper": Filter(
        "median:paper_median_filter",
        False,
        "the paper's modified median (3x3; keeps horizontal/vertical runs of 3)",
    ),
    "thin_wall": Filter(
        "median:thin_wall_median_filter",
        False,
        "the paper's filter also keeping diagonal runs (3x3; thin walls survive)",
    ),
}
if set(FILTERS) != set(FILTER_KINDS) - {"none"}:  # config.FilterKind names them; one list each
    raise ImportError(f"filters.registry implements {sorted(FILTERS)}, config names {FILTER_KINDS}")


def run_filter(
    a: NDArray[ScalarT], kind: FilterKind, size: int, fallback: Fallback
) -> NDArray[ScalarT]:
    """``a`` filtered by the filter named ``kind`` ('none': ``a`` itself): same shape, dtype."""
    if kind == "none":
        return a
    return FILTERS[kind].run(a, size, fallback)
