"""The harness's bounded wait (adclient.testing.workers.wait_for) checks at once, then
ever less often up to its poll: what shows at once is seen soon, a long wait does not ask
the server 20 times a second."""

from __future__ import annotations

import itertools

import pytest

from adclient.testing.workers import pauses, wait_for


def test_the_pauses_grow_from_a_twentieth_of_a_second_to_the_poll() -> None:
    first = list(itertools.islice(pauses(0.25), 8))
    assert first[:5] == pytest.approx([0.05, 0.075, 0.1125, 0.16875, 0.25])
    assert first[5:] == [0.25, 0.25, 0.25]
    assert list(itertools.islice(pauses(0.02), 3)) == [0.02, 0.02, 0.02]  # never past it


def test_the_first_true_value_is_returned_and_checked_at_once() -> None:
    checks = iter([0, "", "found", "later"])
    assert wait_for(lambda: next(checks), "a value") == "found"
    assert next(checks) == "later"  # no check after the true one
