import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from tpos_cli.timebase import in_intervals, true_runs

_value = st.one_of(st.integers(-5, 15).map(float), st.just(float("nan")))


def _by_definition(t, intervals, closed):
    """The mask interval by interval: [a, b) or [a, b]."""
    mask = np.zeros(t.shape, dtype=bool)
    for a, b in np.asarray(intervals, dtype=float).reshape(-1, 2):
        mask |= (t >= a) & ((t <= b) if closed else (t < b))
    return mask


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(_value, _value), max_size=6), st.booleans())
def test_in_intervals_equals_the_union_of_its_intervals(intervals, closed):
    # overlapping, unsorted, empty (start after end), zero-length and NaN intervals; times on the ends
    t = np.arange(-6.0, 17.0, 0.5)
    iv = np.array(intervals, dtype=float).reshape(-1, 2)
    assert np.array_equal(in_intervals(t, iv, closed=closed), _by_definition(t, iv, closed))


def test_in_intervals_of_none_is_nothing():
    assert not in_intervals(np.arange(3.0), None).any() and in_intervals(np.arange(3.0), None).shape == (3,)


def test_true_runs_are_the_half_open_runs():
    starts, ends = true_runs([False, True, True, False, True])
    assert starts.tolist() == [1, 4] and ends.tolist() == [3, 5]
