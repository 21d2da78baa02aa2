"""The detection bench: where in the runs' paths it scores."""

from __future__ import annotations

import pytest

from capsd.bench.detect import RUNS, evaluate
from capsd.cli import main
from capsd.payloads import Detection, SonarFrame
from capsd.simulator.config import OFFLINE_START_NS


class _Stamps:
    """Finds nothing; notes each frame's stamp."""

    def __init__(self) -> None:
        self.stamps: list[int] = []

    def __call__(self, frame: SonarFrame) -> list[Detection]:
        self.stamps.append(frame.stamp_ns)
        return []


def test_a_later_start_scores_that_stretch_of_every_run() -> None:
    first, later = _Stamps(), _Stamps()
    from_start = evaluate({"none": first}, duration_s=1.0, runs=RUNS[:1], looks=("off",))
    from_40 = evaluate({"none": later}, duration_s=1.0, runs=RUNS[:1], looks=("off",), start_s=40.0)
    assert from_start["none / off / all"].frames == len(first.stamps) > 0
    assert from_40["none / off / all"].frames == len(later.stamps) == len(first.stamps)
    # Sim time in the stamps (the sonar's clock may be off by less than a second).
    assert max(first.stamps) - OFFLINE_START_NS < 2e9
    assert min(later.stamps) - OFFLINE_START_NS > 39e9


@pytest.mark.parametrize("start", ["-1", "nan", "2000"])
def test_a_start_outside_the_paths_is_refused(
    start: str, capfd: pytest.CaptureFixture[str]
) -> None:
    assert main(["bench", "detect", "--start", start]) == 2
    assert "--start" in capfd.readouterr().err
