"""How a long fit tells its caller how far it got.

A fit reports ``progress(detail, done, total)``: ``done`` of ``total`` units of work are
finished and ``detail`` names the current step (``"digit 2/3: 17/60 classes"``). The unit is
one class of a digit classifier, the one-vs-rest problem that ``logreg`` and ``svm`` solve
one at a time; ``ridge`` and ``torch`` solve all classes of a digit at once and report them
together. Callbacks may be called from worker threads (one-vs-rest threads), never from
other processes; they should return quickly. An exception raised by a callback aborts the
fit (a training job whose record says it already ended stops this way).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence

#: progress(detail, done, total), called as units of work finish
ProgressFn = Callable[[str, int, int], None]
#: step(done, total) inside one step of a fit (e.g. the classes of one digit)
StepFn = Callable[[int, int], None]
CLASSES = " classes"  # how every per-class detail ends ("digit 1/2: 17/60 classes")


def is_per_class(detail: str) -> bool:
    """True for a report inside a step, False for a step starting or ending: a consumer
    that throttles reports can drop the former but should keep the latter."""
    return detail.endswith(CLASSES)


class Steps:
    """One fit made of consecutive steps with fixed budgets (units of work).

    ``steps.step(i)`` reports step ``i`` as started and returns the :data:`StepFn` its
    trainer calls; ``steps.done(i)`` reports it finished. Thread-safe: a step's trainer may
    report from several threads, and a report never moves the count backwards.
    """

    def __init__(self, progress: ProgressFn | None, labels: Sequence[str],
                 budgets: Sequence[int]) -> None:  # fmt: skip
        if len(labels) != len(budgets):
            raise ValueError("one label per budget")
        self._progress = progress
        self._labels = list(labels)
        self._budgets = [max(0, int(b)) for b in budgets]
        self._offsets = [sum(self._budgets[:i]) for i in range(len(self._budgets))]
        self.total = sum(self._budgets)
        self._done = 0
        self._lock = threading.Lock()

    def _report(self, detail: str, done: int) -> None:
        if self._progress is None:
            return
        with self._lock:
            self._done = max(self._done, done)
            self._progress(detail, self._done, self.total)

    def _at(self, i: int, done: int, total: int) -> int:
        """The overall count when step ``i`` has done ``done`` of its own ``total``."""
        budget = self._budgets[i]
        return self._offsets[i] + (budget * min(done, total) // total if total > 0 else budget)

    def step(self, i: int) -> StepFn | None:
        if self._progress is None:
            return None
        label = self._labels[i]
        self._report(label, self._offsets[i])

        def report(done: int, total: int) -> None:
            classes = f"{done}/{total}{CLASSES}"
            self._report(f"{label}: {classes}" if label else classes, self._at(i, done, total))

        return report

    def scope(self, i: int) -> ProgressFn | None:
        """A :data:`ProgressFn` for step ``i`` when it is itself a fit with progress (its
        reports fill step ``i``'s budget; nothing is reported until the sub-fit reports)."""
        if self._progress is None:
            return None
        label = self._labels[i]

        def report(detail: str, done: int, total: int) -> None:
            self._report(f"{label}: {detail}" if detail else label, self._at(i, done, total))

        return report

    def done(self, i: int) -> None:
        """Step ``i`` finished (reported unless its own reports already said so)."""
        end = self._offsets[i] + self._budgets[i]
        with self._lock:
            reported = self._done >= end
        if not reported:
            self._report(f"{self._labels[i]} done", end)

