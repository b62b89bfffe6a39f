"""What the TLS tests share: the certificates."""
import pytest

from tests.pki import Authority


@pytest.fixture
def pki(tmp_path):
    """(our CA, another CA, the server's (cert, key))."""
    ca = Authority(tmp_path)
    return ca, Authority(tmp_path, "other"), ca.issue("server", server=True)
