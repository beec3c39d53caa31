"""Speed and acceleration limits become whole counts/s for the drives: rounded down, never past the limit."""

import math

import pytest

from drivers.codec import rate_counts_within


@pytest.mark.parametrize(("limit", "counts_per_unit", "counts"), [
    (10.6, 1.0, 10),  # round() sent 11: 0.4 count/s past the limit
    (10.4, 1.0, 10),
    (180.0, 1000.0, 180000),
    (0.29, 100.0, 29),  # 28.999999999999996 in floats: the noise is not a count less
    (1.0, 1.0, 1),
])
def test_a_rate_limit_is_rounded_down_to_whole_counts(limit, counts_per_unit, counts):
    got = rate_counts_within(limit, counts_per_unit)
    assert got == counts
    assert got <= limit * counts_per_unit + 1e-9


@pytest.mark.parametrize("limit", [0.0, -1.0, math.nan, math.inf])
def test_a_rate_limit_that_is_not_a_positive_number_is_refused(limit):
    with pytest.raises(ValueError, match="positive number"):
        rate_counts_within(limit, 1000.0)


@pytest.mark.parametrize(("limit", "counts_per_unit", "counts"), [
    (10.9995, 1.0, 10),  # 0.0005 count under the next: no more forgiven than the float noise
    (0.5, 1.0, 0),  # under one count: none within it (the cell file refuses such a limit)
    (0xFFFFFFFF, 1.0, 0xFFFFFFFF),  # the largest UNSIGNED32
    (0xFFFFFFFF + 0.75, 1.0, 0xFFFFFFFF),  # past it by less than a count: rounded down, it fits
])
def test_rate_limits_at_the_edges_of_a_count_and_of_unsigned32(limit, counts_per_unit, counts):
    assert rate_counts_within(limit, counts_per_unit) == counts


@pytest.mark.parametrize("limit", [2.0**32, 2.0**32 + 1, 1e12])
def test_a_rate_past_unsigned32_is_refused(limit):
    with pytest.raises(ValueError, match="does not fit UNSIGNED32"):
        rate_counts_within(limit, 1.0)
