"""Turn a pydantic ``ValidationError`` on a versioned file into one clear :class:`SetupError`.

Every problem becomes ``item '<dotted.path>' <what is wrong>; fix: <what to give>``, with the fix
taken from the field's ``description`` in the file's pydantic model, so the model documents its
own items once and the error messages follow.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ValidationError

from dimacq.errors import SetupError

__all__ = ["field_description", "refuse"]


def field_description(root: type[BaseModel], loc: tuple[Any, ...]) -> str:
    """The ``description`` of the field at ``loc`` under ``root`` ('' when there is none).

    List indices are skipped; ``Optional``/union annotations are searched for a model.
    """
    model: Any = root
    desc = ""
    for part in loc:
        if isinstance(part, int) or model is None:
            continue
        info = model.model_fields.get(part)
        if info is None:
            return desc
        desc = info.description or ""
        ann = info.annotation
        args = getattr(ann, "__args__", ())
        cand = [a for a in (ann, *args) if isinstance(a, type) and issubclass(a, BaseModel)]
        model = cand[0] if cand else None
    return desc


def refuse(
    kind: str, source: str, err: ValidationError, root: type[BaseModel], hint: str
) -> SetupError:
    """One :class:`SetupError` for every problem of ``err``.

    Parameters
    ----------
    kind : str
        What the file is ("rig file", "scenario"): used in the message.
    source : str
        Its name or path.
    root : pydantic model class
        The model the file was validated against (for the fix hints).
    hint : str
        Where to read more when a field has no description.
    """
    lines = []
    for e in err.errors():
        loc = tuple(e["loc"])
        item = ".".join(str(p) for p in loc) or "(file)"
        msg = e["msg"].removeprefix("Value error, ")
        if e["type"] == "extra_forbidden":
            msg, fix = f"is not a {kind.split()[0]} item", "remove it or correct its spelling"
        elif e["type"] == "missing":
            msg, fix = "is missing", f"add it: {field_description(root, loc) or hint}"
        else:
            desc = field_description(root, loc)
            fix = f"give {desc}" if desc else hint
            if "input" in e and not isinstance(e["input"], dict):
                msg = f"= {e['input']!r}: {msg}"
        lines.append(f"item '{item}' {msg}; fix: {fix}")
    return SetupError(f"{kind} {source} refused: " + " | ".join(lines))
