"""What every `pimbs` command shares: clean error reporting and robot loading.

A researcher at the arm should see one line that says what is wrong and what to do, never
a traceback, for anything the input can get wrong. Programming errors still show their
traceback (they are ours to fix).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, TypeVar

import click

F = TypeVar("F", bound=Callable[..., Any])

# Exceptions whose message is written for the user (they name the file/field/port/board).
USER_ERRORS: tuple[type[BaseException], ...] = (ValueError, OSError, RuntimeError)


def user_errors(func: F) -> F:
    """Turn user-facing exceptions into a clean `Error: ...` and exit status 1."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except click.ClickException:
            raise
        except USER_ERRORS as exc:
            raise click.ClickException(str(exc) or exc.__class__.__name__) from exc

    return wrapper  # type: ignore[return-value]


def robot_option(default: str | None = "two-link-4-muscle") -> Callable[[F], F]:
    """`--robot NAME|PATH`: a built-in robot name or a path to a `.muscles.yaml`."""
    return click.option("--robot", default=default, show_default=default is not None,
                        help="built-in robot name (two-link-4-muscle, left-arm-5dof) or path "
                             "to a .muscles.yaml robot description")
