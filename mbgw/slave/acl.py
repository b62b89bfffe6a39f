"""The authip access list: who may connect as a Modbus TCP client."""
import ipaddress


class AccessList:
    def __init__(self, allowed) -> None:
        self._allowed = frozenset(allowed)

    def allows(self, host: str) -> bool:
        """An empty list lets everyone in.  IPv4-mapped IPv6 peers count as their IPv4 address."""
        if not self._allowed:
            return True
        address = ipaddress.ip_address(host.split("%", 1)[0])
        if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped:
            address = address.ipv4_mapped
        return address in self._allowed
