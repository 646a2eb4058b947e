"""Storage accounting: the paper's formula beside the bytes a model really stores.

The paper counts float64 weights and biases of every class, ``8(d'+1)Στ``, plus one bit per
descriptor column and encoder for the selection masks, ``k·d/8``; with chunks it adds the
chunk classifier, ``8C(d̃+1) + d/8``. ``actual_bytes`` are the tensor bytes of the artifact
at its storage dtype (masks bit-packed, int8 with its per-row scales); the normalisation
statistics are reported on their own line, outside the paper's formula.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any


@dataclass
class ComponentFootprint:
    paper_bytes: float
    actual_bytes: int


@dataclass
class Footprint:
    components: dict[str, ComponentFootprint] = field(default_factory=dict)

    def add(self, name: str, paper_bytes: float, actual_bytes: int) -> None:
        cur = self.components.get(name)
        if cur is None:
            self.components[name] = ComponentFootprint(float(paper_bytes), int(actual_bytes))
        else:
            cur.paper_bytes += float(paper_bytes)
            cur.actual_bytes += int(actual_bytes)

    def merge(self, other: Footprint) -> None:
        for name, comp in other.components.items():
            self.add(name, comp.paper_bytes, comp.actual_bytes)

    @property
    def paper_bytes(self) -> float:
        return sum(c.paper_bytes for c in self.components.values())

    @property
    def actual_bytes(self) -> int:
        return sum(c.actual_bytes for c in self.components.values())

    def to_dict(self) -> dict[str, Any]:
        return {
            "paper_bytes": self.paper_bytes,
            "actual_bytes": self.actual_bytes,
            "components": {k: asdict(v) for k, v in self.components.items()},
        }
