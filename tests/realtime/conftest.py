"""The emulated UR controller every real-time test runs against: one process per test module,
listening on this worker's own loopback address (:mod:`_loopback`), reset before each test."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from _loopback import EMULATOR_PRIORITY, emulator_host

from snac_gym.real.emulator.process import EmulatorProcess


@pytest.fixture(scope="module")
def controller() -> Iterator[EmulatorProcess]:
    with EmulatorProcess(
        series="cb", host=emulator_host(), bind_timeout=90.0, rt_priority=EMULATOR_PRIORITY
    ) as emulator:
        yield emulator


@pytest.fixture
def emu(controller: EmulatorProcess) -> EmulatorProcess:
    controller.reset()
    return controller
