"""`holo token create|list|revoke`: bearer tokens of the service (stored hashed in DATA_DIR/service.db)."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from holo.common import fail

token_app = typer.Typer(help="Service tokens: create (printed once), list, revoke.", no_args_is_help=True)


def register(app: typer.Typer) -> None:
    app.add_typer(token_app, name="token")


def _db(data_dir: Path):
    from service.db import Database

    if not data_dir.exists():
        data_dir.mkdir(parents=True, mode=0o700)  # `holo serve` opens what the sandbox needs when it starts
    return Database(data_dir / "service.db")


@token_app.command("create")
def create(
    data_dir: Path = typer.Option(..., "--data-dir", help="The service's data folder."),
    scope: List[str] = typer.Option(..., "--scope", help="submit | read | admin | agent (repeat for several)."),
    name: str = typer.Option("", "--name", help="A label for the token (at most 100 characters)."),
    owner: str = typer.Option("default", "--owner", help="Whose scenes, jobs and displays the token sees and "
                                                        "makes (a lab or a person; tokens of one owner share)."),
    expires_days: Optional[float] = typer.Option(None, "--expires-days", help="Days until the token stops working "
                                                                             "(default: until revoked)."),
) -> None:
    """Create a token and print it (only its hash is stored: keep the printed value)."""
    from service.auth import create_token

    try:
        _, token = create_token(_db(data_dir), scopes=scope, name=name, owner=owner,
                                expires_in_s=None if expires_days is None else expires_days * 86400.0)
    except ValueError as exc:
        fail(str(exc))
    print(token)


@token_app.command("list")
def list_(data_dir: Path = typer.Option(..., "--data-dir", help="The service's data folder.")) -> None:
    """List tokens (ids, names, scopes; never the secrets)."""
    from service.auth import list_tokens

    for t in list_tokens(_db(data_dir)):
        import time

        state = "revoked" if t["revoked"] else ("expired" if t["expires_at"] and t["expires_at"] <= time.time()
                                                else "active")
        print(f"{t['id']}  {','.join(t['scopes']):<24} {state:<8} {t['owner']:<16} {t['name']}")


@token_app.command("revoke")
def revoke(token_id: str = typer.Argument(..., help="Token id (from `holo token list`)."),
           data_dir: Path = typer.Option(..., "--data-dir", help="The service's data folder.")) -> None:
    """Revoke a token."""
    from service.auth import revoke_token

    if not revoke_token(_db(data_dir), token_id):
        fail(f"no token {token_id!r}")
    print(f"revoked {token_id}")


