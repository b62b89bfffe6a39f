"""authip's rule for the listeners that apply it (slave mode's Modbus TCP server aside): the
table's server (master and transparent modes) and transparent mode's raw port."""
import ipaddress


def access_check(authip: tuple):
    """allows(host): authip's rule (an empty list lets everyone in; IPv4-mapped IPv6 peers
    count as their IPv4 address)."""
    allowed = frozenset(authip)

    def allows(host: str) -> bool:
        if not allowed:
            return True
        address = ipaddress.ip_address(host.split("%", 1)[0])
        if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped:
            address = address.ipv4_mapped
        return address in allowed
    return allows
