"""Which of a run's solutions a deliverable shows by default: the best one the run has.

Order of preference (best first): the smoother's output over any single filter run; the calibrated
federated target solution (paper 001: reference-point calibration) over the plain federated one
(paper 000 Eq. 27), which beats its local filters; the ranging fusion (fatci) over its
tightly/loosely coupled parts; a forward filter over a backward one. Unknown names rank last, in
the order the run wrote them.
"""

from __future__ import annotations

from tpos_cli.errors import InvalidInputError

PREFERENCE = ("smoothed", "fkf_cal", "fkf", "fatci", "tc", "lc", "forward", "lf2", "lf1", "fkf_raw", "backward", "gyro")


def rank_solutions(names) -> list[str]:
    """Solution names, best first (see module docstring)."""
    seen = list(dict.fromkeys(str(n) for n in names))
    known = [s for s in PREFERENCE if s in seen]
    return known + [s for s in seen if s not in known]


def choose_solution(names, requested: str | None, what: str) -> str:
    """`requested` if the run has it, else the best one; InvalidInputError (exit 2) naming the choices."""
    ranked = rank_solutions(names)
    if not ranked:
        raise InvalidInputError(f"{what}: no solution to export")
    if requested is None:
        return ranked[0]
    if requested not in ranked:
        raise InvalidInputError(f"{what}: no solution '{requested}'; the run has: {', '.join(ranked)}")
    return requested
