"""``depthguard keys init|node|admin``: the cell's certificate authority and certificates (R35).

See :mod:`depthguard.transport.keys` for the files and ``docs/THREAT_MODEL.md`` for what
they protect. Private keys are written with mode 0600 and nothing existing is overwritten.
"""

from __future__ import annotations

from pathlib import Path

import typer

from depthguard.cli.app import app

keys_app = typer.Typer(help="Certificates of the distributed mode (R35): the cell's authority, one per camera "
                            "node, one per administrator.", no_args_is_help=True)
app.add_typer(keys_app, name="keys")


@keys_app.command("init")
def init_cmd(
    directory: Path = typer.Argument(..., help="New directory for the authority (ca.pem, ca.key) and the "
                                     "server's certificate (server.pem, server.key). Keep ca.key offline."),
    host: list[str] = typer.Option([], "--host", help="Another host name or IP address the server is reached "
                                   "at (localhost and 127.0.0.1 are always included)."),
) -> None:
    """Create the cell's certificate authority and the fusion server's certificate."""
    from depthguard.transport.keys import init_authority

    out = init_authority(directory, hosts=host)
    typer.echo(f"authority and server certificate in {out} (private keys 0600); "
               f"start the server with --keys {out}")


@keys_app.command("node")
def node_cmd(
    camera: str = typer.Argument(..., help="The camera id (as in the rig) this node may speak for."),
    ca: Path = typer.Option(..., "--ca", help="The authority's directory (`depthguard keys init`)."),
    out: Path = typer.Option(..., "--out", help="New directory for ca.pem, node.pem, node.key."),
) -> None:
    """Issue one camera node's certificate, naming its camera."""
    from depthguard.transport.keys import issue_node

    d = issue_node(camera, ca, out)
    typer.echo(f"certificate of camera {camera} in {d}; run the node with --keys {d}")


@keys_app.command("admin")
def admin_cmd(
    ca: Path = typer.Option(..., "--ca", help="The authority's directory (`depthguard keys init`)."),
    out: Path = typer.Option(..., "--out", help="New directory for ca.pem, admin.pem, admin.key."),
    name: str = typer.Option("admin", "--name", help="Name in the certificate (shown in the server's log)."),
) -> None:
    """Issue an administrator's certificate (`depthguard status`, settings changes)."""
    from depthguard.transport.keys import issue_admin

    d = issue_admin(ca, out, name)
    typer.echo(f"administrator certificate {name!r} in {d}; use it with `depthguard status --keys {d}`")
