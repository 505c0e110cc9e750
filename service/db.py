"""SQLite store of scenes, jobs, sweeps, tokens, idempotency keys and displays (WAL; one connection per thread).

Times are Unix seconds (REAL); JSON columns hold text. State changes of a job are single ``UPDATE ... WHERE
state = ...`` statements, so the scheduler's claim and the API's cancel can never both win.
"""

from __future__ import annotations

import json
import os
import sqlite3
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator, Optional

__all__ = ["Database", "JOB_STATES", "FINAL_STATES"]

JOB_STATES = ("queued", "running", "succeeded", "failed", "cancelled")
FINAL_STATES = ("succeeded", "failed", "cancelled")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS tokens (
    id TEXT PRIMARY KEY, hash TEXT NOT NULL UNIQUE, name TEXT NOT NULL, scopes TEXT NOT NULL,
    created_at REAL NOT NULL, revoked INTEGER NOT NULL DEFAULT 0);
CREATE TABLE IF NOT EXISTS scenes (
    id TEXT PRIMARY KEY, sha256 TEXT NOT NULL, entry TEXT NOT NULL, report TEXT NOT NULL,
    plan_state TEXT NOT NULL, plan TEXT, plan_error TEXT, created_at REAL NOT NULL, plan_updated_at REAL);
CREATE TABLE IF NOT EXISTS jobs (
    id TEXT PRIMARY KEY, state TEXT NOT NULL, display TEXT, scene_id TEXT NOT NULL, spec TEXT NOT NULL,
    cache_key TEXT NOT NULL, created_at REAL NOT NULL, started_at REAL, finished_at REAL,
    progress TEXT, timings TEXT, plan TEXT, error TEXT, attempts INTEGER NOT NULL DEFAULT 0,
    worker_pid INTEGER, stack_sha256 TEXT, stack_bytes INTEGER, artifact_dir TEXT, reused_from TEXT,
    estimate TEXT, artifacts TEXT, token_id TEXT, updated_at REAL NOT NULL);
CREATE INDEX IF NOT EXISTS jobs_state ON jobs(state, created_at);
CREATE INDEX IF NOT EXISTS jobs_display ON jobs(display, created_at);
CREATE INDEX IF NOT EXISTS jobs_key ON jobs(cache_key, state);
CREATE TABLE IF NOT EXISTS idempotency (
    token_id TEXT NOT NULL, key TEXT NOT NULL, body_hash TEXT NOT NULL, job_id TEXT NOT NULL,
    created_at REAL NOT NULL, PRIMARY KEY (token_id, key));
CREATE TABLE IF NOT EXISTS displays (
    name TEXT PRIMARY KEY, last_seen REAL NOT NULL, agent_version TEXT, showing TEXT, state TEXT,
    message TEXT, token_id TEXT);
CREATE TABLE IF NOT EXISTS scene_owners (
    scene_id TEXT NOT NULL, owner TEXT NOT NULL, created_at REAL NOT NULL, PRIMARY KEY (scene_id, owner));
CREATE TABLE IF NOT EXISTS display_sends (display TEXT NOT NULL, job_id TEXT NOT NULL, sent_at REAL NOT NULL,
    token_id TEXT, PRIMARY KEY (display, job_id));
CREATE TABLE IF NOT EXISTS sweeps (id TEXT PRIMARY KEY, owner TEXT NOT NULL, doc TEXT NOT NULL, created_at REAL);
CREATE INDEX IF NOT EXISTS display_sends_job ON display_sends(job_id);
"""
# A job is shown on the display it was submitted for, and on every display it was sent to afterwards
# (POST /v1/jobs/{id}/display): a send is a row of display_sends, so sending a job to one display takes it
# from no other. A display's jobs are ordered by when each was last sent to it (a submit counts as a send at
# the job's created_at): databases from before sends have no rows there and keep the submit order.
# Columns added after the first release (tenancy, token expiry): added in place to older databases.
_ADDED_COLUMNS = {"tokens": {"owner": "TEXT", "expires_at": "REAL"}, "jobs": {"owner": "TEXT"},
                  "displays": {"owner": "TEXT", "agent_token": "TEXT"}}

_JSON_COLS = {"report", "plan", "spec", "progress", "timings", "estimate", "scopes", "showing", "artifacts"}


def _row(cur: sqlite3.Cursor, values: tuple) -> dict:
    out = {}
    for (name, *_), v in zip(cur.description, values):
        out[name] = json.loads(v) if name in _JSON_COLS and isinstance(v, str) else v
    return out


class Database:
    """Thread-safe access to ``service.db``: each thread gets its own connection."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        # owner-only from its first byte, whatever the umask of whoever makes it (`holo token create` before
        # the first `holo serve`); SQLite gives the -wal and -shm files the database file's mode
        try:
            os.close(os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
        except FileExistsError:
            pass
        self._local = threading.local()
        self._conn().executescript(_SCHEMA)
        self._migrate()

    def _migrate(self) -> None:
        conn = self._conn()
        for table, cols in _ADDED_COLUMNS.items():
            have = {r["name"] for r in conn.execute(f"PRAGMA table_info({table})").fetchall()}
            for col, kind in cols.items():
                if col not in have:
                    try:
                        conn.execute(f"ALTER TABLE {table} ADD COLUMN {col} {kind}")
                    except sqlite3.OperationalError:  # a concurrent process added it first
                        pass

    def _conn(self) -> sqlite3.Connection:
        conn = getattr(self._local, "conn", None)
        if conn is None:
            conn = sqlite3.connect(self.path, timeout=30.0, isolation_level=None, check_same_thread=False)
            conn.row_factory = _row
            conn.execute("PRAGMA journal_mode=WAL")
            conn.execute("PRAGMA synchronous=NORMAL")
            conn.execute("PRAGMA busy_timeout=30000")
            self._local.conn = conn
        return conn

    @contextmanager
    def tx(self) -> Iterator[sqlite3.Connection]:
        """A write transaction (BEGIN IMMEDIATE ... COMMIT, rolled back on error)."""
        conn = self._conn()
        conn.execute("BEGIN IMMEDIATE")
        try:
            yield conn
        except BaseException:
            conn.execute("ROLLBACK")
            raise
        conn.execute("COMMIT")

    def query(self, sql: str, params: tuple | dict = ()) -> list[dict]:
        return self._conn().execute(sql, params).fetchall()

    def one(self, sql: str, params: tuple | dict = ()) -> Optional[dict]:
        rows = self._conn().execute(sql, params).fetchall()  # fetchall: an UPDATE ... RETURNING must finish
        return rows[0] if rows else None

    def execute(self, sql: str, params: tuple | dict = ()) -> int:
        """Run one statement (autocommit); returns the number of rows changed."""
        return self._conn().execute(sql, params).rowcount

    def ping(self) -> bool:
        try:
            return self.one("SELECT 1 AS ok")["ok"] == 1
        except sqlite3.Error:
            return False

    # ---- jobs ------------------------------------------------------------------------------------------
    def get_job(self, job_id: str) -> Optional[dict]:
        return self.one("SELECT * FROM jobs WHERE id = ?", (job_id,))

    def insert_job(self, job: dict[str, Any], conn: Optional[sqlite3.Connection] = None) -> None:
        row = {k: (json.dumps(v) if k in _JSON_COLS and v is not None else v) for k, v in job.items()}
        row.setdefault("updated_at", time.time())
        cols = ", ".join(row)
        marks = ", ".join(f":{k}" for k in row)
        (conn or self._conn()).execute(f"INSERT INTO jobs ({cols}) VALUES ({marks})", row)

    def update_job(self, job_id: str, *, where_state: Optional[tuple[str, ...]] = None, **fields: Any) -> bool:
        """Set fields of a job (JSON columns encoded); with ``where_state`` only if its state is one of them.
        Returns whether a row changed."""
        fields["updated_at"] = time.time()
        sets = ", ".join(f"{k} = :{k}" for k in fields)
        params = {k: (json.dumps(v) if k in _JSON_COLS and v is not None else v) for k, v in fields.items()}
        params["_id"] = job_id
        sql = f"UPDATE jobs SET {sets} WHERE id = :_id"
        if where_state:
            marks = ", ".join(f":_s{i}" for i in range(len(where_state)))
            sql += f" AND state IN ({marks})"
            params.update({f"_s{i}": s for i, s in enumerate(where_state)})
        return self.execute(sql, params) > 0

    def next_queued_job(self) -> Optional[dict]:
        """The queued job to run next (:meth:`queued_jobs_fair`'s first)."""
        rows = self.queued_jobs_fair(limit=1)
        return rows[0] if rows else None

    def queued_jobs_fair(self, limit: int = 20) -> list[dict]:
        """Queued jobs in the order they should run: round robin over owners (each owner's k-th oldest job
        after every owner's (k-1)-th, an owner's running jobs counting as its first ones); within a round the
        owner whose last job started longest ago (never: first) goes first. One owner's hundred queued jobs then
        delay another owner's one by at most a job per worker, not by a hundred."""
        same = "COALESCE(r.owner, 'default') = COALESCE(j.owner, 'default')"
        rows = self.query(
            "SELECT j.*, ROW_NUMBER() OVER (PARTITION BY COALESCE(j.owner, 'default') ORDER BY j.created_at, j.rowid)"
            f" + (SELECT COUNT(*) FROM jobs r WHERE r.state = 'running' AND {same}) AS _round, "
            f"(SELECT MAX(r.started_at) FROM jobs r WHERE r.state != 'queued' AND {same}) AS _served "
            "FROM jobs j WHERE j.state = 'queued' ORDER BY _round, COALESCE(_served, 0), j.created_at, j.rowid "
            "LIMIT ?", (int(limit),))
        for r in rows:
            r.pop("_round", None)
            r.pop("_served", None)
        return rows

    def count_owner_jobs(self, owner: str, states: tuple[str, ...]) -> int:
        marks = ", ".join("?" for _ in states)
        return self.one(f"SELECT COUNT(*) AS n FROM jobs WHERE COALESCE(owner, 'default') = ? AND state IN ({marks})",
                        (owner, *states))["n"]

    def claim_next_job(self, job_id: Optional[str] = None) -> Optional[dict]:
        """Atomically move the oldest queued job (or ``job_id``, if still queued) to running (attempts + 1) and
        return it, or None."""
        now = time.time()
        if job_id is not None:
            return self.one("UPDATE jobs SET state = 'running', attempts = attempts + 1, started_at = ?, "
                            "updated_at = ?, worker_pid = NULL, error = NULL WHERE id = ? AND state = 'queued' "
                            "RETURNING *", (now, now, job_id))
        return self.one(
            "UPDATE jobs SET state = 'running', attempts = attempts + 1, started_at = ?, updated_at = ?, "
            "worker_pid = NULL, error = NULL WHERE id = (SELECT id FROM jobs WHERE state = 'queued' "
            "ORDER BY created_at, rowid LIMIT 1) AND state = 'queued' RETURNING *", (now, now))

    def delete_job(self, job_id: str, *, where_state: tuple[str, ...]) -> bool:
        """Remove a job's row and its idempotency records, only while its state is one of ``where_state``."""
        marks = ", ".join("?" for _ in where_state)
        with self.tx() as conn:
            n = conn.execute(f"DELETE FROM jobs WHERE id = ? AND state IN ({marks})", (job_id, *where_state)).rowcount
            if n:
                conn.execute("DELETE FROM idempotency WHERE job_id = ?", (job_id,))
                conn.execute("DELETE FROM display_sends WHERE job_id = ?", (job_id,))
        return bool(n)

    def jobs_with_artifact_dir(self, artifact_dir: str) -> int:
        """How many jobs hold their files in ``artifact_dir`` (reused results share their first job's)."""
        return self.one("SELECT COUNT(*) AS n FROM jobs WHERE artifact_dir = ?", (artifact_dir,))["n"]

    def list_jobs(self, *, state: Optional[str] = None, display: Optional[str] = None,
                  scene_id: Optional[str] = None, owner: Optional[str] = None, limit: int = 50) -> list[dict]:
        """Jobs newest first; ``owner`` limits them to one owner's (None: everyone's). With ``display``: the jobs
        submitted for it or sent to it, the most recently sent first (each row's ``sent_at``: its last send to
        that display, else its submit time)."""
        where, params = [], []
        for col, value in (("jobs.state", state), ("jobs.scene_id", scene_id),
                           ("COALESCE(jobs.owner, 'default')", owner)):
            if value is not None:
                where.append(f"{col} = ?")
                params.append(value)
        if display is None:
            sql = "SELECT * FROM jobs" + (" WHERE " + " AND ".join(where) if where else "")
            sql += " ORDER BY created_at DESC, rowid DESC LIMIT ?"
            return self.query(sql, (*params, int(limit)))
        # Two halves, each on an index (an OR of them would read every job of the state): the display's own jobs
        # never sent to it, at their submit time, and the jobs sent to it, at their last send there.
        also = "".join(f" AND {w}" for w in where)
        sql = ("SELECT * FROM (SELECT jobs.*, jobs.created_at AS sent_at, jobs.rowid AS _rowid FROM jobs "
               "WHERE jobs.display = ? AND jobs.id NOT IN (SELECT job_id FROM display_sends WHERE display = ?)"
               f"{also} UNION ALL SELECT jobs.*, s.sent_at AS sent_at, jobs.rowid AS _rowid FROM display_sends s "
               f"JOIN jobs ON jobs.id = s.job_id WHERE s.display = ?{also}) ORDER BY sent_at DESC, _rowid DESC LIMIT ?")
        rows = self.query(sql, (display, display, *params, display, *params, int(limit)))
        for r in rows:
            r.pop("_rowid", None)
        return rows

    def send_job(self, job_id: str, display: str, *, token_id: Optional[str]) -> Optional[float]:
        """Make ``job_id`` the job ``display`` shows next: record that it was sent there now, only while it is
        succeeded. Returns the time of the send (Unix seconds), None when the job is not (or no longer) succeeded."""
        now = time.time()
        with self.tx() as conn:
            done = conn.execute("SELECT 1 AS ok FROM jobs WHERE id = ? AND state = 'succeeded'", (job_id,)).fetchone()
            if done is None:
                return None
            conn.execute("INSERT INTO display_sends (display, job_id, sent_at, token_id) VALUES (?, ?, ?, ?) "
                         "ON CONFLICT (display, job_id) DO UPDATE SET sent_at = excluded.sent_at, "
                         "token_id = excluded.token_id", (display, job_id, now, token_id))
        return now

    def count_jobs(self, owner: Optional[str] = None) -> dict[str, int]:
        """Jobs by state (``owner``: that owner's only; None: everyone's)."""
        counts = {s: 0 for s in JOB_STATES}
        if owner is None:
            rows = self.query("SELECT state, COUNT(*) AS n FROM jobs GROUP BY state")
        else:
            rows = self.query("SELECT state, COUNT(*) AS n FROM jobs WHERE COALESCE(owner, 'default') = ? "
                              "GROUP BY state", (owner,))
        for r in rows:
            counts[r["state"]] = r["n"]
        return counts

    def owner_scene_bytes(self, owner: str) -> int:
        """Bytes of the unpacked bundles of ``owner``'s scenes (from their reports)."""
        return int(self.one("SELECT COALESCE(SUM(json_extract(s.report, '$.total_bytes')), 0) AS n FROM scenes s "
                            "JOIN scene_owners o ON o.scene_id = s.id WHERE o.owner = ?", (owner,))["n"] or 0)

    def owner_job_folders(self, owner: str) -> list[dict]:
        """State, folder and (while queued or running) stored options and estimate of each of ``owner``'s jobs,
        reused results included: a folder is held by every job that points at it, whichever computed it."""
        return self.query("SELECT id, state, artifact_dir, CASE WHEN state IN ('queued', 'running') THEN spec END "
                          "AS spec, CASE WHEN state IN ('queued', 'running') THEN estimate END AS estimate FROM jobs "
                          "WHERE COALESCE(owner, 'default') = ?", (owner,))

    def count_scenes(self, owner: str) -> int:
        return self.one("SELECT COUNT(*) AS n FROM scene_owners WHERE owner = ?", (owner,))["n"]

    def running_jobs(self) -> list[dict]:
        return self.query("SELECT * FROM jobs WHERE state = 'running'")

    def succeeded_jobs_with_key(self, cache_key: str, *, owner: str, limit: int = 5) -> list[dict]:
        """The newest succeeded jobs of ``owner`` with content address ``cache_key`` (newest first). Only one
        owner's: a result reused across owners would tell one that another rendered the same thing, and when."""
        return self.query("SELECT * FROM jobs WHERE cache_key = ? AND state = 'succeeded' AND "
                          "COALESCE(owner, 'default') = ? ORDER BY finished_at DESC LIMIT ?",
                          (cache_key, owner, int(limit)))

    # ---- idempotency keys ------------------------------------------------------------------------------
    def get_idempotency(self, token_id: str, key: str) -> Optional[dict]:
        """The record of ``key`` used by token ``token_id`` ({"body_hash", "job_id", ...}), or None."""
        return self.one("SELECT * FROM idempotency WHERE token_id = ? AND key = ?", (token_id, key))

    @staticmethod
    def insert_idempotency(conn: sqlite3.Connection, *, token_id: str, key: str, body_hash: str, job_id: str,
                           created_at: float) -> None:
        """Record an idempotency key inside the transaction ``conn`` (IntegrityError if the key exists)."""
        conn.execute("INSERT INTO idempotency (token_id, key, body_hash, job_id, created_at) VALUES (?, ?, ?, ?, ?)",
                     (token_id, key, body_hash, job_id, created_at))

    # ---- tokens ----------------------------------------------------------------------------------------
    def insert_token(self, *, token_id: str, token_hash: str, name: str, scopes: list[str], created_at: float,
                     owner: str, expires_at: Optional[float]) -> None:
        self.execute("INSERT INTO tokens (id, hash, name, scopes, created_at, owner, expires_at) VALUES "
                     "(?, ?, ?, ?, ?, ?, ?)", (token_id, token_hash, name, json.dumps(scopes), created_at, owner,
                                               expires_at))

    def token_by_hash(self, token_hash: str) -> Optional[dict]:
        return self.one("SELECT id, name, scopes, revoked, owner, expires_at FROM tokens WHERE hash = ?",
                        (token_hash,))

    def revoke_token(self, token_id: str) -> bool:
        return self.execute("UPDATE tokens SET revoked = 1 WHERE id = ?", (token_id,)) > 0

    def list_tokens(self) -> list[dict]:
        return self.query("SELECT id, name, scopes, created_at, revoked, COALESCE(owner, 'default') AS owner, "
                          "expires_at FROM tokens ORDER BY created_at")

    # ---- scenes ----------------------------------------------------------------------------------------
    def get_scene(self, scene_id: str) -> Optional[dict]:
        return self.one("SELECT * FROM scenes WHERE id = ?", (scene_id,))

    def insert_scene(self, scene: dict[str, Any]) -> bool:
        """Insert a scene; False when the id exists already (same content uploaded before)."""
        row = {k: (json.dumps(v) if k in _JSON_COLS and v is not None else v) for k, v in scene.items()}
        cols = ", ".join(row)
        marks = ", ".join(f":{k}" for k in row)
        return self.execute(f"INSERT OR IGNORE INTO scenes ({cols}) VALUES ({marks})", row) > 0

    def update_scene(self, scene_id: str, *, where_plan_state: Optional[str] = None, **fields: Any) -> bool:
        sets = ", ".join(f"{k} = :{k}" for k in fields)
        params = {k: (json.dumps(v) if k in _JSON_COLS and v is not None else v) for k, v in fields.items()}
        params["_id"] = scene_id
        sql = f"UPDATE scenes SET {sets} WHERE id = :_id"
        if where_plan_state is not None:
            sql += " AND plan_state = :_ps"
            params["_ps"] = where_plan_state
        return self.execute(sql, params) > 0

    def requeue_running_plans(self) -> int:
        """Scene plans left running (by a server that stopped) go back to pending; returns how many."""
        return self.execute("UPDATE scenes SET plan_state = 'pending' WHERE plan_state = 'running'")

    def add_scene_owner(self, scene_id: str, owner: str) -> bool:
        """Record that ``owner`` uploaded ``scene_id``; False when it had already."""
        return self.execute("INSERT OR IGNORE INTO scene_owners (scene_id, owner, created_at) VALUES (?, ?, ?)",
                            (scene_id, owner, time.time())) > 0

    def scene_owned_by(self, scene_id: str, owner: str) -> bool:
        return self.one("SELECT 1 AS ok FROM scene_owners WHERE scene_id = ? AND owner = ?",
                        (scene_id, owner)) is not None

    # ---- displays --------------------------------------------------------------------------------------
    def display_owner(self, name: str) -> Optional[str]:
        row = self.one("SELECT owner FROM displays WHERE name = ?", (name,))
        return None if row is None else (row["owner"] or "default")

    def claim_display(self, name: str, owner: str, token_id: str) -> Optional[str]:
        """Register display ``name`` to ``owner`` unless another owner holds it; returns the owner that holds it."""
        self.execute("INSERT OR IGNORE INTO displays (name, last_seen, owner, token_id) VALUES (?, ?, ?, ?)",
                     (name, time.time(), owner, token_id))
        self.execute("UPDATE displays SET owner = ? WHERE name = ? AND owner IS NULL", (owner, name))
        return self.display_owner(name)

    def set_display_owner(self, name: str, owner: str, agent_token: Optional[str] = None) -> bool:
        """Register ``name`` to ``owner`` (``agent_token``: only that token's heartbeats, None: any of the
        owner's agent tokens)."""
        return self.execute("UPDATE displays SET owner = ?, agent_token = ? WHERE name = ?",
                            (owner, agent_token, name)) > 0

    def display_row(self, name: str) -> Optional[dict]:
        return self.one("SELECT name, COALESCE(owner, 'default') AS owner, agent_token FROM displays WHERE name = ?",
                        (name,))

    def heartbeat(self, name: str, *, agent_version: str, showing: Optional[dict], state: str, message: str,
                  token_id: str) -> None:
        self.execute("UPDATE displays SET last_seen = ?, agent_version = ?, showing = ?, state = ?, message = ?, "
                     "token_id = ? WHERE name = ?", (time.time(), agent_version,
                                                     json.dumps(showing) if showing is not None else None, state,
                                                     message, token_id, name))

    def list_displays(self, *, owner: Optional[str] = None) -> list[dict]:
        if owner is None:
            return self.query("SELECT * FROM displays ORDER BY name")
        return self.query("SELECT * FROM displays WHERE COALESCE(owner, 'default') = ? ORDER BY name", (owner,))

    def claim_next_plan(self) -> Optional[dict]:
        """Claim the next pending scene plan: the oldest of the owner whose plans were served longest ago (never
        first), so owners take turns and one owner's hundred uploads do not hold every other owner's plans back."""
        owner = "(SELECT MIN(o.owner) FROM scene_owners o WHERE o.scene_id = {s}.id)"
        served = (f"(SELECT MAX(t.plan_updated_at) FROM scenes t WHERE t.plan_state != 'pending' AND "
                  f"{owner.format(s='t')} = {owner.format(s='s')})")
        return self.one(
            f"UPDATE scenes SET plan_state = 'running', plan_updated_at = ? WHERE id = (SELECT s.id FROM scenes s "
            f"WHERE s.plan_state = 'pending' ORDER BY COALESCE({served}, 0), s.created_at, s.rowid LIMIT 1) "
            "AND plan_state = 'pending' RETURNING *", (time.time(),))
