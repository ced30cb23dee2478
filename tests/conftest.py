"""Shared fixtures. Tests that talk over DDS get their own ROS domain and localhost-only discovery."""
import itertools
import os

import pytest

_domains = itertools.count()


def pytest_configure(config):
    config.addinivalue_line('markers', 'slow: long-running; deselect with -m "not slow"')


def isolated_ros_env(mp: pytest.MonkeyPatch) -> int:
    """Give this process (and the nodes it starts) a ROS domain of its own, discovery on localhost."""
    domain = 1 + (os.getpid() + 17 * next(_domains)) % 100
    mp.setenv('ROS_DOMAIN_ID', str(domain))
    mp.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    return domain


@pytest.fixture
def ros_domain(monkeypatch):
    return isolated_ros_env(monkeypatch)


@pytest.fixture(scope='module')
def module_ros_domain():
    with pytest.MonkeyPatch.context() as mp:
        yield isolated_ros_env(mp)
