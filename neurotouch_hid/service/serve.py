"""What answers the user while a run goes on: the control socket (``profile use``, ``status``:
:mod:`neurotouch_hid.service.control`) and the games watcher (a game's own profile while it runs:
:mod:`neurotouch_hid.service.games`), started by the driver around the engine's run and stopped
after it. The engine knows neither: they call its :meth:`use_profile`.
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import TYPE_CHECKING, Iterator, Protocol

if TYPE_CHECKING:
    from neurotouch_hid.core.stats import RunStats
    from neurotouch_hid.engine.loop import Loop


class Switchable(Protocol):
    """What the services ask of a run (:class:`~neurotouch_hid.engine.engine.Engine`).

    Attributes:
        stats: the run's counters (the game followed).
        loop: where the services wait (:class:`~neurotouch_hid.engine.loop.Loop`): the run's
            main thread serves it.
    """

    stats: RunStats
    loop: Loop

    @property
    def profile_name(self) -> str:
        """The profile in use as the user named it."""

    def use_profile(self, ref: str, reason: str | None = None) -> str:
        """Switch to the profile ``ref``; the line said. Raises ProfileError to refuse it."""


@contextlib.contextmanager
def served(
    run: Switchable, profile_ref: str | Path | None, *, serial: str | None = None, games: bool = False
) -> Iterator[None]:
    """Serve ``run`` while the block runs: its control socket (:func:`~neurotouch_hid.service.
    control.socket_path` of the camera ``serial``: its own socket) and, with ``games`` and a
    ``profile_ref`` to come back to (the profile the run started with), the games watcher on the
    camera's games.yaml (:func:`~neurotouch_hid.service.serials.sensor_file`; else the shared one).
    Both wait on the run's loop (no thread of their own); each is stopped on the way out. A
    control socket that cannot be made is logged (the run goes on without it:
    :meth:`~neurotouch_hid.service.control.ControlServer.start`)."""
    from neurotouch_hid.service.control import ControlServer, socket_path

    watcher = None
    with contextlib.ExitStack() as stack:
        if games and profile_ref is not None:
            from neurotouch_hid.service.games import GameProfiles, games_file
            from neurotouch_hid.service.serials import sensor_file

            def follow(game) -> None:
                run.stats.note(game=game.label() if game is not None else "")

            path = sensor_file(serial, "games", games_file())
            watcher = GameProfiles(run.use_profile, str(profile_ref), path=path, on_game=follow)
            watcher.start(run.loop)
            stack.callback(watcher.stop)
        server = ControlServer(
            watcher.manual_use if watcher is not None else run.use_profile,
            socket_path(serial),
            status=lambda: f"profile {run.profile_name}",
        )
        server.start(run.loop)
        stack.callback(server.stop)
        yield
