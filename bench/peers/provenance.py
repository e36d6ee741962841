"""Provenance of peer rows: who measured them, when, with which versions, on which CPU.

Every peer script stamps its rows with `stamp(rows, script, versions)` before writing
`target/pbdl/bench/<crate>_peers.json`; `cargo xtask bench` refuses peer rows without this
stamp and prints each source beside the table, so a peer number always says where it came from.
"""
import os
import platform
import time


def cpu_model():
    """The CPU model name from /proc/cpuinfo (Linux), else platform.processor()."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def versions_of(*modules):
    """'name version, ...' for imported modules (a module that has no __version__ says '?')."""
    out = []
    for m in modules:
        name = getattr(m, "__name__", str(m))
        out.append(f"{name} {getattr(m, '__version__', '?')}")
    out.append(f"python {platform.python_version()}")
    return ", ".join(out)


def versions_named(*names):
    """Like versions_of, for module names (imported here; a missing one says 'missing')."""
    mods = []
    for n in names:
        try:
            mods.append(__import__(n))
        except Exception:
            mods.append(type("Missing", (), {"__name__": n, "__version__": "missing"}))
    return versions_of(*mods)


def stamp(rows, script, versions):
    """Adds `measured` = {script, date, versions, cpu} to every row that has none; returns rows."""
    measured = {
        "script": os.path.relpath(os.path.abspath(script), os.path.join(os.path.dirname(__file__), "..", "..")),
        "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "versions": versions,
        "cpu": cpu_model(),
    }
    for r in rows:
        r.setdefault("measured", dict(measured))
    return rows
