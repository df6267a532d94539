"""Settling the ``concurrent.futures.Future`` of a call, goal or request from the network or timer thread."""

from __future__ import annotations

from concurrent.futures import Future, InvalidStateError
from typing import Any


def settle(future: Future[Any], *, result: Any = None, error: BaseException | None = None) -> None:
    """Give ``future`` its result or exception, unless its owner cancelled it meanwhile (then: nothing)."""
    try:
        if error is not None:
            future.set_exception(error)
        else:
            future.set_result(result)
    except InvalidStateError:  # the caller cancelled it, or a timeout and a reply raced: the first one counts
        pass
