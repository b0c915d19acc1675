"""The ur_rtde client process's answers to its parent (snac_gym/real/rtde_client.py): how a failed request is named."""

from __future__ import annotations

import pytest

from snac_gym.real.rtde_client import Client, _answer


class _Receive:
    pass


def _client(link: bool | None) -> Client:
    """A client whose command raises as ur_rtde does during its own reconnect; its link up, down, or unknowable
    (``None``: asking raises too)."""
    client = Client()
    client.receive = _Receive()

    def command(*args: object) -> None:
        raise RuntimeError("Timeout connecting to UR dashboard server.\nmore")

    def link_up() -> bool:
        if link is None:
            raise RuntimeError("no answer")
        return link

    client.command = command  # type: ignore[method-assign]
    client.link_up = link_up  # type: ignore[method-assign]
    return client


@pytest.mark.parametrize(
    ("link", "answer"),
    [
        (False, ("lost", "was lost (RuntimeError: Timeout connecting to UR dashboard server.)")),
        (True, ("error", "RuntimeError: Timeout connecting to UR dashboard server.")),
        (None, ("error", "RuntimeError: Timeout connecting to UR dashboard server.")),
    ],
)
def test_a_request_that_fails_with_the_link_down_is_a_lost_link_in_ur_rtdes_words(link, answer):
    # The parent words a "lost" answer "connection to the arm at HOST was lost (...)", an "error" one
    # "ur_rtde command failed: ...": under load ur_rtde raised from its reconnect before it said it reconnects.
    assert _answer(_client(link), "command", ()) == answer


def test_a_request_before_any_connection_is_an_error_not_a_lost_link():
    client = Client()  # never connected: no link to have lost

    def state() -> None:
        raise RuntimeError("not connected")

    client.state = state  # type: ignore[method-assign]
    assert _answer(client, "state", ()) == ("error", "RuntimeError: not connected")
