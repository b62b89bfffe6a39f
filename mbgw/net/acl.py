"""authip: who may connect to mbgw's Modbus TCP listeners (slave mode's server, the table's
server, transparent mode's raw port)."""
import ipaddress


class AccessList:
    """allows(host) by authip's addresses (config's, ip_address objects)."""

    def __init__(self, allowed) -> None:
        self._allowed = frozenset(allowed)

    def allows(self, host: str) -> bool:
        """An empty list lets everyone in.  A peer is compared without its scope id, and an
        IPv4-mapped IPv6 peer as its IPv4 address."""
        if not self._allowed:
            return True
        address = ipaddress.ip_address(host.split("%", 1)[0])
        if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped:
            address = address.ipv4_mapped
        return address in self._allowed
