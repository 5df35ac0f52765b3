"""One way to say what a pydantic validation error found: ``key.path: message (got value)``."""

from __future__ import annotations

from pydantic import ValidationError


def describe_validation_error(err: ValidationError, prefix: str = "",
                              show_input: bool = True) -> str:
    """The first error of ``err`` as ``where: what (got value)``; ``prefix`` is prepended to
    the location (e.g. ``services.sim`` for a table of a deployment file)."""
    first = err.errors()[0]
    where = ".".join(str(p) for p in (*([prefix] if prefix else []), *first["loc"]))
    got = first.get("input")
    msg = first["msg"].removeprefix("Value error, ")
    if first["type"] == "extra_forbidden":
        msg = "unknown key"
    shown = (show_input and first["type"] != "missing" and not isinstance(got, dict | list))
    got_text = f" (got {_short(got)})" if shown else ""
    return f"{where or '(top level)'}: {msg}{got_text}"


def _short(value: object, limit: int = 60) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."
