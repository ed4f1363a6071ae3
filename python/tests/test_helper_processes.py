"""Helper processes (cnfmp.helper_processes): a real second interpreter answers handlers in
order, hands back what they raise, and is reported gone (not waited on) when it dies."""

from __future__ import annotations

import os
import signal

import pytest

from cnfmp import helper_processes


@pytest.fixture
def helper():
    helper_processes.stop()
    assert helper_processes.start(1) == 1
    yield helper_processes.helpers()[0]
    helper_processes.stop()


def test_a_helper_runs_handlers_in_another_process_in_the_order_submitted(helper):
    assert helper.submit("os:getpgid", 0).result(timeout=60) == os.getpgid(0)  # same group: our child
    futures = [helper.submit("math:sqrt", float(n * n)) for n in range(20)]
    assert [f.result(timeout=60) for f in futures] == [float(n) for n in range(20)]
    assert helper.process.pid != os.getpid() and helper.process.poll() is None
    assert helper_processes.start(1) == 1, "start is idempotent"


def test_what_a_handler_raises_comes_back_and_the_helper_keeps_serving(helper):
    with pytest.raises(ValueError, match="math domain error"):
        helper.submit("math:sqrt", -1.0).result(timeout=60)
    with pytest.raises(ModuleNotFoundError):
        helper.submit("no_such_module:f", None).result(timeout=60)
    assert helper.submit("math:sqrt", 9.0).result(timeout=60) == 3.0


def test_a_dead_helper_is_reported_and_dropped(helper):
    assert helper.submit("math:sqrt", 4.0).result(timeout=60) == 2.0
    os.kill(helper.process.pid, signal.SIGKILL)
    helper.process.wait(timeout=30)
    with pytest.raises(helper_processes.HelperError, match="is gone"):
        helper.submit("math:sqrt", 4.0).result(timeout=60)
    assert helper_processes.helpers() == []
    with pytest.raises(helper_processes.HelperError, match="is gone"):
        helper.submit("math:sqrt", 1.0).result(timeout=60)


def test_a_helper_exits_when_its_parent_closes_it(helper):
    process = helper.process
    helper_processes.stop()
    assert process.wait(timeout=10) == 0
    assert helper_processes.helpers() == []


def test_a_negative_count_is_refused():
    with pytest.raises(ValueError, match=">= 0"):
        helper_processes.start(-1)
