"""Slave mode's passthrough with the exchange table on (issue 14): requests for the serial
slaves still cross the line unchanged and in order, now that every reply is written by
Python under the gate (no forward from C, no shortcut) and the table reader may read the
clients during a transaction.  The tests are test_passthrough's own, run against a gateway
with --table; the table units (247-254) are not used here."""
import pytest

from tests.integration.slave.test_passthrough import (  # noqa: F401 (fixtures and tests rerun here)
    client,
    connect,
    test_a_client_pipelining_beyond_16_requests_gets_every_answer,
    test_a_pipelining_client_does_not_starve_another,
    test_mbpoll_writes,
    test_pipelined_requests_are_answered_in_order,
    test_pymodbus_client_reads_every_table,
    test_pymodbus_client_writes_and_reads_back,
    test_reply_passes_byte_exact,
)

pytestmark = pytest.mark.integration


@pytest.fixture
def gateway(pty_pair, start_peer, start_gateway):
    """test_passthrough's gateway (pymodbus slaves 17 and 42 on the line), with the table on."""
    start_peer("pymodbus_slave.py", pty_pair.device, "17", "42", "--identity")
    return start_gateway(pty_pair.gateway, "--baudrate", "19200", "--table")
