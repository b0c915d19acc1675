"""How a real run may resume after a protective stop or a lost link: opt-in, bounded, never past a safety rule.

With ``max_recoveries`` = 0 (the default) a protective stop ends the episode and a lost link ends
the run, as they always did. Above 0, :class:`~snac_gym.real.env.RealUREnv` may resume the same
episode up to that many times:

* **protective stop**: the arm is stopped, then the env waits (at most ``clear_timeout``) for the
  stop to be cleared: by the operator on the pendant, or, only with ``unlock_protective_stop``,
  by the dashboard server's ``unlock protective stop`` once UR's 5 s lockout
  (:data:`~snac_gym.real.connections.PROTECTIVE_STOP_LOCKOUT`) has passed since the host saw it;
* **lost link**: a new ur_rtde client connects, attempts every
  :attr:`~snac_gym.real.connections.URRTDEConnection.RECONNECT_PAUSE` s for at most
  ``reconnect_timeout`` s; a link that does not come back ends the run as before.

Either way, before any command: a state package newer than the first one read (at most
``fresh_state_timeout`` s), the controller in its normal safety state, the arm at rest, and
every start check of ``reset`` (finite state, joint margin, task box, TCP position against the
model's f(θ)). The command then starts again from rest, so the acceleration bound holds from the
first period; that period (which also re-uploads the control script and arms the watchdog) is not
counted by the late-loop rule, as the episode's first is not. An emergency stop is never resumed.
"""

from __future__ import annotations

from dataclasses import dataclass

from snac_gym.real.safety import check_finite_in, check_whole_in

PROTECTIVE_STOP_RECOVERY = "protective stop"
LINK_RECOVERY = "lost link"


@dataclass(frozen=True)
class RecoveryLimits:
    """Whether and how far a real episode resumes after an interruption (see the module docs).

    Attributes:
        max_recoveries: Resumptions allowed per episode, protective stops and lost links together
            (0: none, every interruption ends the episode as before), in [0, 100].
        unlock_protective_stop: Unlock a protective stop from the dashboard server once UR's 5 s
            lockout has passed (else only the operator clears it, on the pendant).
        clear_timeout: Longest wait (s) for a protective stop to be cleared, in (0, 3600].
        reconnect_timeout: Longest time (s) for a lost link to come back, in (0, 600].
        fresh_state_timeout: Longest wait (s) for a state package newer than the first read
            before resuming, in (0, 10].
    """

    max_recoveries: int = 0
    unlock_protective_stop: bool = False
    clear_timeout: float = 60.0
    reconnect_timeout: float = 10.0
    fresh_state_timeout: float = 1.0

    def __post_init__(self) -> None:
        check_whole_in("max_recoveries", self.max_recoveries, 0, 100)
        check_finite_in("clear_timeout", self.clear_timeout, 0.0, 3600.0, low_open=True)
        check_finite_in("reconnect_timeout", self.reconnect_timeout, 0.0, 600.0, low_open=True)
        check_finite_in("fresh_state_timeout", self.fresh_state_timeout, 0.0, 10.0, low_open=True)
        if self.unlock_protective_stop and self.max_recoveries == 0:
            raise ValueError("unlocking a protective stop needs max_recoveries of at least 1 (--max-recoveries N)")
