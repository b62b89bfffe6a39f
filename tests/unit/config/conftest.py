import pytest

from mbgw.cli import main
from mbgw.config import schema as config_keys


@pytest.fixture
def schema() -> config_keys.Schema:
    return config_keys.Schema(main)
