"""A stop signal at any moment of start-up is one line and exit 130 (issue 39, item 3): during the imports it is
kept and raised after them (``deferred``), never inside one, where a KeyboardInterrupt in a compiled module's
initialisation becomes ``ImportError: initialization failed`` (a traceback) or is swallowed by a ``try: import``
(the run went on); a stop that became another error is still reported as the stop. Real signals, in process."""

from __future__ import annotations

import contextlib
import os
import signal

import pytest

from common import stop_signals

pytestmark = pytest.mark.realtime  # timing-sensitive: make test runs these alone, after the rest


def _send(signum: int) -> None:
    """``signum`` to this process: its Python handler runs as this call returns."""
    os.kill(os.getpid(), signum)


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_stop_during_the_imports_is_raised_after_them_not_inside(signum):
    reached = []
    with pytest.raises(KeyboardInterrupt) as info, stop_signals.deferred():
        try:
            _send(signum)  # an import's initialisation would turn an exception raised here into ImportError
            reached.append("after")
        except ImportError:
            pass
    assert reached == ["after"]  # nothing was raised inside the block
    assert stop_signals.reason_of(info.value) == stop_signals.reason(signum)


def test_a_stop_swallowed_by_an_import_still_stops_the_command_in_one_line(capsys):
    def body() -> int:
        # a "try: import fast_module / except ImportError: fallback" that a stop ran into
        with stop_signals.deferred(), contextlib.suppress(ImportError):
            _send(signal.SIGTERM)
        return 0  # the command would have gone on to run a whole session

    assert stop_signals.guarded("acquire", body) == 130
    assert capsys.readouterr().err == "acquire: stopped by SIGTERM\n"


def test_a_stop_that_became_an_import_error_is_reported_as_the_stop(capsys):
    def body() -> int:
        try:
            _send(signal.SIGTERM)  # raising: Stopped, inside a compiled module's initialisation ...
        except KeyboardInterrupt:
            raise ImportError("initialization failed") from None  # ... which reports it as this
        return 0

    assert stop_signals.guarded("identify", body) == 130
    assert capsys.readouterr().err == "identify: stopped by SIGTERM\n"


def test_an_error_without_a_stop_is_not_taken_for_one():
    with pytest.raises(ImportError):
        stop_signals.guarded("identify", lambda: (_ for _ in ()).throw(ImportError("no module")))
