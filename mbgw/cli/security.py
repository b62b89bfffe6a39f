"""`mbgw config show --security`: the security settings a configuration file puts in force,
for a review: the listeners (where, plain or TLS, their limits), TLS (versions and suites
offered, the CA, the CRL), authip, the firewall, the web console (never a password hash),
the metrics and control endpoints, and who may read the file itself.  report() is the JSON
document; text() its readable form."""
import grp
import os
import pwd
import ssl
import stat
from pathlib import Path

from mbgw.config.file import Settings
from mbgw.config.schema import NO_ADDRESS, Schema
from mbgw.errors import ConfigError
from mbgw.net.tls import MAX_HANDSHAKES
from mbgw.ops.control import default_path as control_default_path

ALL_ADDRESSES = "all addresses (IPv4 and IPv6)"


def report(schema: Schema, settings: Settings) -> dict:
    def get(name: str):
        return settings.get(schema, name) if name in schema.keys else None

    authip = [a for a in get("authip") or [] if a != NO_ADDRESS]
    tls = _tls(get)
    return {"file": _file_access(settings.path), "mode": settings.mode,
            "listeners": _listeners(settings.mode, get, tls["enabled"], authip),
            "authip": authip, "tls": tls, "firewall": _firewall(settings),
            "web": _web(get), "control": _control(get("control"))}


def _listeners(mode: str, get, tls: bool, authip: list) -> list[dict]:
    bind = get("bind") or ALL_ADDRESSES
    allowed = authip or "any client"
    out = []
    table_limit = get("table-max-connections")
    if mode == "slave":
        limits = {"max_connections": get("max-connections"),
                  "max_connections_per_ip": get("max-connections-per-ip") or None}
        if get("mdbport"):
            out.append({"name": "modbus", "address": bind, "port": get("mdbport"),
                        "transport": "plain", **limits, "authip": allowed})
        if tls:
            out.append({"name": "modbus-tls", "address": bind, "port": get("tls-port"),
                        "transport": "tls", **limits, "handshakes_at_once": MAX_HANDSHAKES,
                        "authip": allowed})
    elif mode == "master":
        if get("enabled"):
            out.append({"name": "table", "address": bind, "port": get("port"),
                        "transport": "plain", "max_connections": table_limit,
                        "authip": allowed})
            if tls:
                out.append({"name": "table-tls", "address": bind,
                            "port": get("tls-port"), "transport": "tls",
                            "max_connections": table_limit, "authip": allowed})
    else:
        if get("mdbport"):
            out.append({"name": "table", "address": bind, "port": get("mdbport"),
                        "transport": "plain", "max_connections": table_limit,
                        "authip": allowed})
        if tls:
            out.append({"name": "table-tls", "address": bind, "port": get("tls-port"),
                        "transport": "tls", "max_connections": table_limit,
                        "authip": allowed})
        if get("raw-port"):
            out.append({"name": "raw", "address": bind, "port": get("raw-port"),
                        "transport": "plain", "max_connections": 1, "authip": allowed})
    if get("web"):
        out.append({"name": "web", "listen": get("web"),
                    "transport": "https" if get("web-cert") else "http"})
    if get("metrics"):
        out.append({"name": "metrics", "listen": get("metrics"), "transport": "http",
                    "authentication": "none"})
    return out


def _tls(get) -> dict:
    """The server side's TLS: the files, and what a context built from them offers (the
    files are read as the daemon reads them: an error says why they would be refused)."""
    from mbgw.config.model import TlsConfig
    from mbgw.net.tls import server_context
    cert, key, ca, crl = get("cert"), get("key"), get("ca"), get("crl")
    out: dict = {"enabled": cert is not None, "cert": cert, "key": key, "ca": ca, "crl": crl,
                 "client_certificate": "required" if cert else None,
                 "require_role": bool(get("require-role")) if cert else None}
    if cert is None:
        return out
    try:
        context = server_context(TlsConfig(port=get("tls-port"), cert=cert, key=key, ca=ca,
                                           require_role=bool(get("require-role")), crl=crl))
    except ConfigError as err:
        return {**out, "error": str(err)}
    versions = [v for v in (ssl.TLSVersion.TLSv1_2, ssl.TLSVersion.TLSv1_3)
                if context.minimum_version <= v <= context.maximum_version]
    names = {v.name.replace("TLSv1_", "TLSv1."): v for v in versions}
    return {**out, "versions": list(names),
            "suites": [c["name"] for c in context.get_ciphers() if c["protocol"] in names]}


def _firewall(settings: Settings) -> dict:
    fw = settings.firewall
    return {"default": fw.default, "rules": [
        {"rule": r.index, "selects": r.describe(),
         "units": list(r.units) if r.units is not None else "all",
         "functions": list(r.functions) if r.functions is not None else "all",
         "registers": [f"{a}-{b}" for a, b in r.registers] if r.registers is not None
         else "all",
         "read_only": r.read_only} for r in fw.rules]}


def _web(get) -> dict:
    return {"listen": get("web"), "https": get("web-cert") is not None,
            "cert": get("web-cert"),
            "users": [role for role in ("admin", "user") if get(f"{role}-password")]}


def _control(path: str | None) -> dict:
    path = path or control_default_path()
    return {"path": path, **(_owner(Path(path)) or {"exists": False})}


def _owner(path: Path) -> dict | None:
    try:
        st = os.stat(path)
    except OSError:
        return None
    try:
        owner = pwd.getpwuid(st.st_uid).pw_name
    except KeyError:
        owner = str(st.st_uid)
    try:
        group = grp.getgrgid(st.st_gid)
        group_name, members = group.gr_name, list(group.gr_mem)
    except KeyError:
        group_name, members = str(st.st_gid), []
    mode = stat.S_IMODE(st.st_mode)
    return {"exists": True, "owner": owner, "group": group_name, "group_members": members,
            "mode": f"{mode:04o}", "group_can_read": bool(mode & stat.S_IRGRP),
            "others_can_read": bool(mode & stat.S_IROTH),
            "others_can_write": bool(mode & stat.S_IWOTH)}


def _file_access(path: Path) -> dict:
    return {"path": str(path), **(_owner(path) or {"exists": False})}


# --- the readable form --------------------------------------------------------------------------

def text(r: dict) -> list[str]:
    f = r["file"]
    lines = [f"file       {f['path']}"]
    if f["exists"]:
        members = f" ({', '.join(f['group_members'])})" if f["group_members"] else ""
        lines.append(f"           owner {f['owner']}, group {f['group']}{members}, mode "
                     f"{f['mode']}: other users {'CAN' if f['others_can_read'] else 'cannot'}"
                     f" read it" + (" and CAN WRITE it" if f["others_can_write"] else ""))
    else:
        lines.append("           does not exist: built-in defaults")
    lines.append(f"mode       {r['mode']}")
    lines.append("listeners")
    for li in r["listeners"]:
        where = li.get("listen") or f"{li['address']} port {li['port']}"
        limits = [f"{k.replace('_', ' ')} {v}" for k, v in li.items()
                  if k in ("max_connections", "max_connections_per_ip", "handshakes_at_once")
                  and v]
        extra = [f"authip {', '.join(li['authip'])}" if isinstance(li.get("authip"), list)
                 else li.get("authip")]
        if li.get("authentication") == "none":
            extra.append("no authentication")
        lines.append(f"  {li['name']:<11}{li['transport']:<6} {where}"
                     + "".join(f"; {x}" for x in [*limits, *extra] if x))
    if not r["listeners"]:
        lines.append("  (none)")
    t = r["tls"]
    if t["enabled"]:
        lines.append(f"tls        cert {t['cert']}, key {t['key']}, client CA {t['ca']}; "
                     f"client certificate required"
                     + ("; a certificate without a role may do nothing" if t["require_role"]
                        else ""))
        if "error" in t:
            lines.append(f"           refused as it stands: {t['error']}")
        else:
            lines.append(f"           versions {', '.join(t['versions'])}")
            lines.append(f"           suites {', '.join(t['suites'])}")
        lines.append(f"           CRL {t['crl'] or '(none: revoked certificates are not refused)'}")
    else:
        lines.append("tls        off")
    lines.append("authip     " + (", ".join(r["authip"]) or "(empty: any client may connect)"))
    fw = r["firewall"]
    lines.append(f"firewall   default {fw['default']}, {len(fw['rules'])} rules")
    for rule in fw["rules"]:
        grants = [f"units {_listed(rule['units'])}", f"functions {_listed(rule['functions'])}",
                  f"registers {_listed(rule['registers'])}"]
        if rule["read_only"]:
            grants.append("read-only")
        lines.append(f"  {rule['selects']}: {', '.join(grants)}")
    w = r["web"]
    if w["listen"]:
        lines.append(f"web        {w['listen']} {'HTTPS' if w['https'] else 'HTTP (no TLS)'}; "
                     f"passwords set: {', '.join(w['users']) or 'none'}")
    else:
        lines.append("web        off")
    c = r["control"]
    state = (f"owner {c['owner']}, group {c['group']}, mode {c['mode']}" if c["exists"]
             else "not there now (the daemon makes it 0660, root and group mbgw)")
    lines.append(f"control    {c['path']}: {state}")
    return lines


def _listed(value) -> str:
    return value if isinstance(value, str) else ",".join(map(str, value))
