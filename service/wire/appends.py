"""The options of an append (``POST /v1/maps/{name}/versions/{v}/traversals``), as form
fields beside the traversal files, and the condition tags they carry."""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import Annotated

from pydantic import Field

from service.errors import InvalidInputError
from service.wire.base import Request

# no \s: JSON Schema's (ECMAScript) and pydantic's (Rust) classes differ (U+0085), so a value
# is any characters but '=' and the schema accepts exactly what the server does
TAG_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}=[^=]{1,200}$"
MAX_TAGS = 32
_TAG = re.compile(TAG_PATTERN)
Tag = Annotated[str, Field(pattern=TAG_PATTERN, description="a condition tag key=value",
                           examples=["season=winter"])]  # fmt: skip


def parse_tags(items: Sequence[str]) -> dict[str, str]:
    """Condition tags ``key=value`` (a key of letters, digits, ``_.-`` up to 64 characters;
    a value up to 200 characters without ``=``): a bad or repeated one is an
    :class:`InvalidInputError` naming it."""
    if len(items) > MAX_TAGS:
        raise InvalidInputError(f"{len(items)} tags given; at most {MAX_TAGS}", tags=len(items))
    tags: dict[str, str] = {}
    for item in items:
        if _TAG.match(item) is None:
            raise InvalidInputError(
                f"tag {item!r} is not key=value (a key of letters, digits, '_', '.', '-'; a "
                "value without '='), e.g. season=winter", tag=item,
            )  # fmt: skip
        key, value = item.split("=", 1)
        if key in tags:
            raise InvalidInputError(f"tag {key!r} is given twice", tag=key)
        tags[key] = value
    return tags


class AppendOptions(Request):
    """How the traversals are appended; every field optional."""

    tag: list[Tag] = Field(
        default_factory=list, max_length=MAX_TAGS,
        description="condition tags key=value of the traversals (repeat the field), e.g. "
        "season=winter, time=night; recorded in the new version's traversals",
    )  # fmt: skip
    extend: bool = Field(False, description="places beyond the route extend it (each needs a "
                         "row); every existing place keeps its index")  # fmt: skip
    whiten: bool | None = Field(
        None, description="learn the traversals' within-place scatter and whiten the projected "
        "space by it (unset: where the model allows it, one class per place)",
    )  # fmt: skip
    activate: bool = Field(False, description="activate the new version at once")
    retrain: bool = Field(
        False, description="instead of appending, train a new version as a job from every "
        "traversal the version was built from plus these (what an extension its code's "
        "periods cannot label needs): 202 with the job (GET /v1/jobs/{id}); its version is "
        "activated as any trained version is (POST …/activate). Not with whiten or activate",
    )  # fmt: skip

    def check_retrain(self) -> None:
        """A retrain takes tags and extend; whiten and activate belong to appends."""
        given = [k for k in ("whiten", "activate") if k in self.model_fields_set]
        if self.retrain and given:
            raise InvalidInputError(f"{', '.join(given)} applies to appends, not to retrain=true",
                                    fields=given)  # fmt: skip

    def tags(self) -> dict[str, str]:
        """The tags as a mapping (a key given twice is an error naming it: 400)."""
        return parse_tags(self.tag)

    def form(self) -> dict[str, str | list[str]]:
        """The multipart form fields (only the options that were set)."""
        out: dict[str, str | list[str]] = {}
        if self.tag:
            out["tag"] = list(self.tag)
        for key in ("extend", "whiten", "activate", "retrain"):
            value = getattr(self, key)
            if value is not None and key in self.model_fields_set:
                out[key] = str(value).lower()
        return out
