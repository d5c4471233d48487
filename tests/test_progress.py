"""The one progress helper (photonflow.progress) and the one speed of light."""

from __future__ import annotations

from photonflow import constants
from photonflow.generator import constants as generator_constants
from photonflow.progress import with_progress
from photonflow.transport import direct, optics


def test_items_pass_through_in_order_with_or_without_a_bar(capsys):
    items = [3, 1, 4, 1, 5]
    assert list(with_progress(items, "counting")) == items
    assert list(with_progress(iter(items), "counting", total=10, completed=5)) == items
    assert list(with_progress((x for x in items), "counting", show=False)) == items
    assert capsys.readouterr().out == ""  # the bar never writes to standard output


def test_a_generator_is_consumed_lazily():
    seen = []

    def produce():
        for i in range(3):
            seen.append(i)
            yield i

    iterator = with_progress(produce(), "lazy", total=3)
    assert seen == []
    assert next(iterator) == 0 and seen == [0]


def test_one_speed_of_light():
    assert optics.SPEED_OF_LIGHT is constants.SPEED_OF_LIGHT
    assert direct.SPEED_OF_LIGHT is constants.SPEED_OF_LIGHT
    assert generator_constants.SPEED_OF_LIGHT == constants.SPEED_OF_LIGHT * 100.0  # cm/ns
    assert constants.SPEED_OF_LIGHT == 0.299792458  # m/ns, exact by the SI definition
