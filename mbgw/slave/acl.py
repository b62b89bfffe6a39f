"""Moved to mbgw.net.acl; slave/server.py imports it from here until it imports mbgw.net.acl
(then this file goes)."""
from mbgw.net.acl import AccessList

__all__ = ["AccessList"]
