"""The energy ledger (docs/model.md, "The Zeno guard"): what holds removed is booked apart from
the impact law's losses — in `Simulation`, the energy error, the summary line, the impact log,
the bag (read back with the `mcap` package's own reader) — and a hold over its bound is one
warning line.
"""
import json
import math
import warnings

import pytest
from mcap.reader import make_reader

from engine_cases import one_link_doc, simulation
from mobile_manip_sim.engine import events
from mobile_manip_sim.engine.impact_log import (
    LOG_HELD,
    LOG_HOLD_BOUND,
    LOG_HOLD_LOST,
    LOG_LD_BEFORE,
    LOG_LINK,
    LOG_SIDE,
    LOG_TIME,
)
from mobile_manip_sim.recording.bag_format import (
    LEDGER_KEYS,
    LEDGER_NAME,
    checked_energy_ledger,
    energy_ledger,
)
from mobile_manip_sim.recording.headless import HeadlessRecorder
from mobile_manip_sim.runtime.headless import run as headless_run
from mobile_manip_sim.runtime.headless import summary_line
from mobile_manip_sim.scene.errors import UserError

VERTICAL = dict(joints=(math.pi / 2, 0.5), stroke=(0.0, 1.0))   # rod 1 straight up


def chattering_doc():
    """A vertical rod falling onto its lower stop, e = 0.5, rest_speed 0: held once, at its
    accumulation point (test_end_stops.py has its closed form)."""
    doc = one_link_doc(**VERTICAL, effects={"gravity": 10.0, "stroke_limits": {
        "restitution": 0.5, "rest_speed": 0.0}})
    doc["integrator"] = {"method": "rk4", "dt": 1e-3}
    return doc


def test_a_hold_is_booked_apart_and_shows_in_the_energy_error_and_the_summary():
    sim = simulation(chattering_doc())
    sim.advance_to(1.2)
    assert sim.holds == 1 and sim.impacts[-1].held
    assert sim.hold_energy == sim.impacts[-1].hold_energy > 0.0
    assert sim.hold_energy <= events.ZENO_SHARE * 5.0   # ½ m v₀² = 5 J at the first impact
    # the law's losses alone balance the trajectory; what the hold removed is error
    assert sim.impact_energy_lost == pytest.approx(sum(i.energy_lost for i in sim.impacts))
    assert sim.energy_error() == pytest.approx(-sim.hold_energy, abs=1e-9)
    line = summary_line(sim, 1.0)
    assert f"{len(sim.impacts)} impacts, 1 holds removing {sim.hold_energy:.3e} J, " in line
    assert "\n" not in line
    row = sim.impacts[-1].as_dict()   # the impact log's columns (FILE.impacts.csv)
    assert row["held"] is True and row["hold_energy"] == sim.hold_energy


def test_a_run_without_holds_says_nothing_of_them():
    doc = chattering_doc()
    doc["effects"]["stroke_limits"]["rest_speed"] = 1e-3
    sim = simulation(doc)
    sim.advance_to(1.2)
    assert sim.holds == 0 and sim.hold_energy == 0.0 and sim.impacts
    assert "holds" not in summary_line(sim, 1.0)


def test_the_bag_carries_the_ledger(tmp_path):
    from mobile_manip_sim.scene.loading import parse_scene
    scene = parse_scene(chattering_doc())
    recorder = HeadlessRecorder(tmp_path / "bag", scene, scene.integrator, 100.0, 1.2)
    try:
        sim = headless_run(scene, 1.2, 100.0, on_sample=recorder.sample)
    finally:
        recorder.close()
    metadata, attachments = {}, {}
    for path in sorted((tmp_path / "bag").glob("*.mcap")):
        with path.open("rb") as handle:
            reader = make_reader(handle)
            metadata.update({m.name: dict(m.metadata) for m in reader.iter_metadata()})
            attachments.update({a.name: bytes(a.data) for a in reader.iter_attachments()})
    ledger = checked_energy_ledger(metadata[LEDGER_NAME])
    assert ledger == {"impacts": len(sim.impacts), "impact_energy_lost": sim.impact_energy_lost,
                      "holds": 1, "hold_energy": sim.hold_energy}
    records = json.loads(attachments["impacts.json"])
    assert [r["held"] for r in records] == [False] * (len(records) - 1) + [True]
    assert records[-1]["hold_energy"] == sim.hold_energy


@pytest.mark.parametrize("key, value", [("holds", "-1"), ("holds", "1.5"), ("hold_energy", "x"),
                                        ("hold_energy", "nan"), ("impacts", None)])
def test_a_damaged_ledger_is_one_line_naming_the_key(key, value):
    ledger = energy_ledger([{"energy_lost": 0.5, "held": True, "hold_energy": 1e-9}])
    assert set(ledger) == set(LEDGER_KEYS)
    if value is None:
        del ledger[key]
    else:
        ledger[key] = value
    with pytest.raises(UserError) as caught:
        checked_energy_ledger(ledger)
    assert key in str(caught.value) and "\n" not in str(caught.value)


def test_a_hold_over_its_bound_is_one_warning_line_as_it_is_collected():
    """The report path itself: a held row whose energy exceeds its bound (which the Zeno guard
    never produces; a rod found at its stop moving away could) is said on one line."""
    sim = simulation(chattering_doc())
    log = sim.stops.log[0]
    log[:] = 0.0
    log[LOG_TIME], log[LOG_LINK], log[LOG_SIDE], log[LOG_LD_BEFORE] = 0.25, 1, -1, 0.5
    log[LOG_HELD], log[LOG_HOLD_LOST], log[LOG_HOLD_BOUND] = 1.0, 0.125, 1e-6
    sim.stops.count[0] = 1
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sim._collect_impacts()
    assert len(caught) == 1 and "\n" not in str(caught[0].message)
    assert "rod 1 held at its lower stop" in str(caught[0].message)
    assert "0.125 J beyond the impact law" in str(caught[0].message)
    lines = []
    sim.hold_warning = lines.append   # the node's logger takes the same line
    log[LOG_HOLD_BOUND] = 0.2
    sim.stops.count[0] = 1
    sim._collect_impacts()
    assert lines == []
