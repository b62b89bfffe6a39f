"""Moved to mbgw.net.tls.  What is left here serves slave/server.py and master/line_thread.py
until they import mbgw.net.tls themselves (then this file goes)."""
from mbgw.net.tls import client_context, role_of, server_context

__all__ = ["client_context", "role_of", "server_context"]
