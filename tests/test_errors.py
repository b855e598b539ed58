"""Every bvm error has one root, and keeps the bases hosts already catch."""

from __future__ import annotations

import pytest

import bvm
from bvm import wire
from bvm.budget import BudgetTimeout


@pytest.mark.parametrize(
    "error",
    [
        bvm.BuzzCompileError,
        bvm.BuzzAsmError,
        bvm.BuzzLoadError,
        bvm.BuzzError,
        bvm.BuzzBudgetExceeded,
        BudgetTimeout,
        wire.DecodeError,
        wire.EncodeError,
    ],
)
def test_every_error_is_a_bvm_error(error: type[Exception]) -> None:
    assert issubclass(error, bvm.BvmError)


def test_wire_errors_are_still_value_errors() -> None:
    assert issubclass(wire.DecodeError, ValueError)
    assert issubclass(wire.EncodeError, ValueError)
    with pytest.raises(ValueError):
        wire.decode(b"")


def test_errors_raised_by_the_api_are_caught_by_the_root() -> None:
    with pytest.raises(bvm.BvmError):
        bvm.compile_source("x = ", "bad.bzz")
    vm = bvm.VM()
    vm.load(bvm.compile_source("x = nil + 1", "bad.bzz"))
    with pytest.raises(bvm.BvmError):
        vm.execute()
