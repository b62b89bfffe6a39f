import shutil

import pytest

from tests.harness import factory
from tests.peers.broker import MOSQUITTO, Broker, Subscriber


@pytest.fixture
def broker(tmp_path):
    """Debian's Mosquitto on 127.0.0.1 (scripts/setup.sh installs it)."""
    if shutil.which(MOSQUITTO) is None:
        pytest.skip("mosquitto is not installed (scripts/setup.sh installs it)")
    started = Broker(tmp_path)
    yield started
    started.stop()


@pytest.fixture
def subscribe():
    """subscribe(port, *topics) -> a Subscriber; closed after the test."""
    yield from factory(Subscriber, Subscriber.close)
