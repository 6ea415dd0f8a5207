"""Single-input single-output fuzzy inference system (paper 002, Sec. 4.3, Algorithm 1, Eq. 31).

Mamdani inference: triangular memberships for the input (the range SD) and the output (the
coefficient S), rules "if input is A then output is B", min implication, max aggregation and
centroid ("gravity") defuzzification. The measurement noise of a range is then
`R = S^b R_ref` (Eq. 31). The rule base and breakpoints come from the pipeline TOML
(`tpos_cli.config.FuzzyParams`, validated there).

Eq. 31 is garbled in the text ("Rii1 = Spy Ry"); we read it as `R_k = S_k^b R_ref` applied per
range with a fixed reference `R_ref`, because a recursive `R_{k+1} = S^b R_k` would drift without
bound for S != 1 (Fig. 18 shows S oscillating around 1, i.e. a per-epoch scaling).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tpos_cli.ranging._kernels import mamdani_centroid

_GRID_POINTS = 2001  # inputs checked for a firing rule


@dataclass(frozen=True)
class FuzzySystem:
    """SISO Mamdani system.

    in_sets, out_sets : name -> (left, peak, right) triangle breakpoints
    rules : tuple of (input set, output set)
    in_range, out_range : universes of discourse; inputs are clamped to in_range
    """

    in_sets: dict[str, tuple[float, float, float]]
    out_sets: dict[str, tuple[float, float, float]]
    rules: tuple[tuple[str, str], ...]
    in_range: tuple[float, float]
    out_range: tuple[float, float]


def triangle(x: np.ndarray, abc: tuple[float, float, float]) -> np.ndarray:
    """Triangular membership with feet a, c and peak b; a == b or b == c gives a shoulder edge."""
    a, b, c = abc
    x = np.asarray(x, dtype=float)
    left = np.where(x < b, (x - a) / (b - a) if b > a else 1.0, 1.0)
    right = np.where(x > b, (c - x) / (c - b) if c > b else 1.0, 1.0)
    return np.clip(np.minimum(left, right), 0.0, 1.0) * ((x >= a) & (x <= c))


def uncovered_input(in_sets: dict, rules, in_range) -> float | None:
    """The first input in `in_range` at which no rule fires, or None when the rule base covers it.

    Every input in the universe must fire some rule, or the output would be undefined there
    (`tpos_cli.config.FuzzyParams` refuses such a rule base before any data is read).
    """
    x = np.linspace(in_range[0], in_range[1], _GRID_POINTS)
    fired = np.max([triangle(x, in_sets[r_in]) for r_in, _ in rules], axis=0)
    return float(x[np.argmax(fired <= 0.0)]) if np.any(fired <= 0.0) else None


def infer(fis: FuzzySystem, x: np.ndarray) -> np.ndarray:
    """Crisp output S for each input x (fuzzify, min-implication, max-aggregation, centroid).

    Inputs are clamped to the input universe; where no rule fires the output is the middle of
    the output universe (cannot happen with a covering rule base, checked by the tests). The
    aggregated membership is piecewise linear, so its centroid is computed exactly, piece by
    piece (`_kernels.mamdani_centroid`), not by quadrature on a grid.
    """
    x = np.ascontiguousarray(np.atleast_1d(np.asarray(x, dtype=float)).ravel())
    in_names, out_names = list(fis.in_sets), list(fis.out_sets)
    in_tri = np.array([fis.in_sets[k] for k in in_names], dtype=float).reshape(-1, 3)
    out_tri = np.array([fis.out_sets[k] for k in out_names], dtype=float).reshape(-1, 3)
    rule_in = np.array([in_names.index(a) for a, _ in fis.rules], dtype=np.int64)
    rule_out = np.array([out_names.index(b) for _, b in fis.rules], dtype=np.int64)
    out = np.empty(x.size)
    mamdani_centroid(x, float(fis.in_range[0]), float(fis.in_range[1]), in_tri, out_tri, rule_in, rule_out,
                     float(fis.out_range[0]), float(fis.out_range[1]), 0.5 * (fis.out_range[0] + fis.out_range[1]), out)
    return out


def fuzzy_system(rule_base) -> FuzzySystem:
    """The FuzzySystem of a validated rule base (`tpos_cli.config.FuzzyParams`: input_sets,
    output_sets, rules, input_range, output_range)."""
    return FuzzySystem(dict(rule_base.input_sets), dict(rule_base.output_sets), tuple(rule_base.rules),
                       tuple(rule_base.input_range), tuple(rule_base.output_range))
