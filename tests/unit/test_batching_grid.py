"""Which micro-batch wait the grpc benchmark recommends from its grid."""

from __future__ import annotations

from typing import Any

from service.bench.batching_grid import best_wait


def _grid(rates: dict[str, tuple[float, list[float]]]) -> dict[str, Any]:
    return {k: {"streams": {"frames_per_s": r}, "rounds_frames_per_s": rounds}
            for k, (r, rounds) in rates.items()}  # fmt: skip


def test_a_longer_wait_must_beat_the_noise_of_the_shortest() -> None:
    noisy = _grid({"0": (5200.0, [4000.0, 6500.0]), "0.5": (4600.0, [4500.0, 4700.0]),
                   "2": (5800.0, [5000.0, 6600.0])})  # fmt: skip
    assert best_wait(noisy) == "0"
    clear = _grid({"0": (5200.0, [5100.0, 5300.0]), "2": (5800.0, [5700.0, 5900.0])})
    assert best_wait(clear) == "2"


def test_the_shortest_wait_wins_when_it_is_fastest() -> None:
    assert best_wait(_grid({"2": (4000.0, [3900.0, 4100.0]), "0": (5000.0, [4000.0, 6000.0])})) == "0"


def test_two_identical_servers_set_the_noise() -> None:
    grid = _grid({"0": (3200.0, [3100.0, 3300.0]), "2": (5300.0, [5200.0, 5400.0]),
                  "0 (repeat)": (7000.0, [6900.0, 7100.0])})  # fmt: skip
    assert best_wait(grid) == "0"  # identical servers differ by more than 2 ms gains
