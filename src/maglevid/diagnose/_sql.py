"""Connections, transactions with retry, and migrations for the history store.

Two backends behind one small interface (:class:`Backend`): SQLite (a file, no
server) and PostgreSQL (through psycopg 3, imported only when a PostgreSQL URL is
opened). The public API lives in :mod:`maglevid.diagnose.history`; this module
knows SQL dialects and failure modes, not diagnoses.

Concurrency design (see ``docs/history.md``)
--------------------------------------------
SQLite: write-ahead log (``journal_mode=WAL``) so readers never block writers;
``synchronous=FULL`` so a committed transaction survives power loss as well as a
killed process; every write transaction starts with ``BEGIN IMMEDIATE`` so it
takes the single writer lock *before* reading (no read-to-write upgrade, hence
no deadlock between two writers); ``busy_timeout`` makes SQLite itself wait for
the lock, and :meth:`Backend.run` retries the whole transaction with jittered
exponential backoff on the few ``SQLITE_BUSY``/``SQLITE_LOCKED`` answers that
do not wait, until the store's timeout.

PostgreSQL: each write is one transaction at READ COMMITTED; inserts use
``ON CONFLICT DO NOTHING`` on the natural keys, which waits for a concurrent
inserter of the same key and then yields to it, so two writers of the same
diagnosis end with one row. Serialization failures and deadlocks (SQLSTATE
40001, 40P01) are retried like SQLite's busy answers. Migrations take a
transaction-scoped advisory lock so that concurrent first openings create the
schema once.
"""

from __future__ import annotations

import logging
import os
import random
import re
import sqlite3
import time
import urllib.parse
from collections.abc import Callable, Iterable, Sequence
from datetime import datetime, timezone
from typing import Any, TypeVar
from urllib.parse import urlsplit, urlunsplit

from maglevid.diagnose._migrations import MIGRATIONS, VERSION_TABLE, Migration, render
from maglevid.exceptions import MaglevidError

__all__ = [
    "Backend",
    "HistoryError",
    "NotFoundError",
    "SchemaVersionError",
    "StoreBusyError",
    "connect",
    "migrate",
    "redact_url",
]

logger = logging.getLogger(__name__)

T = TypeVar("T")

#: SQLite ``PRAGMA application_id`` of a maglevid history file ("MLVH").
APPLICATION_ID = 0x4D4C5648

#: Default PostgreSQL schema (namespace) of the store's tables.
DEFAULT_PG_SCHEMA = "maglevid"

_SCHEMA_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]{0,62}$")
_STORE_TABLES = {"schema_migrations", "machines", "recordings", "diagnoses", "estimates"}


class HistoryError(MaglevidError, RuntimeError):
    """The history store cannot be opened, read or written as asked."""


class SchemaVersionError(HistoryError):
    """The store's schema is newer than this maglevid, or is not a history store."""


class StoreBusyError(HistoryError):
    """A transaction could not get the store's lock before the timeout."""


class NotFoundError(HistoryError, LookupError):
    """No machine, parameter or diagnosis of that name or id in the store."""


def redact_url(url: str) -> str:
    """``url`` with its password replaced by ``***`` (for messages and logs)."""
    parts = urlsplit(url)
    if parts.password is None:
        return url
    netloc = parts.netloc.rsplit("@", 1)
    userinfo = netloc[0].split(":", 1)[0] + ":***"
    return urlunsplit(parts._replace(netloc=userinfo + "@" + netloc[1]))


def parse_target(target: str | os.PathLike[str]) -> tuple[str, str]:
    """Split a store location into ``(dialect, location)``.

    A plain path (or ``:memory:``) and ``sqlite:///relative`` /
    ``sqlite:////absolute`` (SQLAlchemy's convention) open SQLite;
    ``postgresql://...`` or ``postgres://...`` open PostgreSQL.
    """
    if isinstance(target, os.PathLike):
        return "sqlite", os.fspath(target)
    if not isinstance(target, str) or not target:
        raise HistoryError(
            f"store location must be a path or URL string; got {type(target).__name__} {target!r}"
        )
    lower = target.lower()
    for scheme in ("postgresql://", "postgres://", "postgresql+psycopg://"):
        if lower.startswith(scheme):
            return "postgresql", "postgresql://" + target[len(scheme) :]
    if lower.startswith("sqlite://"):
        rest = target[len("sqlite://") :]
        if rest in ("", "/", "/:memory:"):
            return "sqlite", ":memory:"
        if not rest.startswith("/"):
            raise HistoryError(
                f"store URL {target!r}: expected sqlite:///relative/path or "
                "sqlite:////absolute/path"
            )
        return "sqlite", rest[1:]
    if "://" in target:
        raise HistoryError(
            f"store URL {redact_url(target)!r}: unknown scheme; expected a path, "
            "sqlite:///path or postgresql://user:password@host:port/database"
        )
    return "sqlite", target


class Tx:
    """The statements of one transaction: ``?`` placeholders in every dialect."""

    def __init__(self, conn: Any, dialect: str):
        self._conn = conn
        self.dialect = dialect

    def _sql(self, sql: str) -> str:
        return sql.replace("?", "%s") if self.dialect == "postgresql" else sql

    def execute(self, sql: str, params: Sequence[Any] = ()) -> Any:
        return self._conn.execute(self._sql(sql), tuple(params))

    def executemany(self, sql: str, rows: Iterable[Sequence[Any]]) -> None:
        if self.dialect == "postgresql":
            with self._conn.cursor() as cur:
                cur.executemany(self._sql(sql), [tuple(r) for r in rows])
        else:
            self._conn.executemany(sql, [tuple(r) for r in rows])

    def one(self, sql: str, params: Sequence[Any] = ()) -> Any:
        """First column of the first row, or ``None``."""
        row = self.execute(sql, params).fetchone()
        return None if row is None else row[0]

    def all(self, sql: str, params: Sequence[Any] = ()) -> list[tuple[Any, ...]]:
        return [tuple(r) for r in self.execute(sql, params).fetchall()]

    # -- values that differ by dialect -------------------------------------
    def ts_in(self, t: datetime) -> Any:
        """A UTC datetime as the column stores it (fixed-width ISO text in SQLite)."""
        t = t.astimezone(timezone.utc)
        if self.dialect == "postgresql":
            return t
        return t.strftime("%Y-%m-%dT%H:%M:%S.%f+00:00")

    @staticmethod
    def ts_out(v: Any) -> datetime:
        if isinstance(v, datetime):
            return v.astimezone(timezone.utc)
        return datetime.fromisoformat(v).astimezone(timezone.utc)


class Backend:
    """One open connection, its dialect, and the retrying transaction runner.

    Not shareable between processes or threads: open one store per process.
    """

    def __init__(
        self, conn: Any, dialect: str, description: str, *, timeout: float, schema: str | None
    ):
        self.conn = conn
        self.dialect = dialect
        self.description = description
        self.timeout = float(timeout)
        self.schema = schema
        self.pid = os.getpid()
        self.tx = Tx(conn, dialect)
        self.closed = False

    # -- failure classification --------------------------------------------
    def _transient(self, exc: BaseException) -> bool:
        """Whether ``exc`` means "try the transaction again" (lock contention)."""
        if self.dialect == "sqlite":
            if not isinstance(exc, sqlite3.OperationalError):
                return False
            code = getattr(exc, "sqlite_errorcode", None)
            if code is not None:
                return (code & 0xFF) in (5, 6)  # SQLITE_BUSY, SQLITE_LOCKED (+ extended codes)
            msg = str(exc).lower()
            return "locked" in msg or "busy" in msg
        sqlstate = getattr(exc, "sqlstate", None)
        return sqlstate in ("40001", "40P01", "55P03")

    def _db_error_types(self) -> tuple[type[BaseException], ...]:
        if self.dialect == "sqlite":
            return (sqlite3.Error,)
        import psycopg

        return (psycopg.Error,)

    def _in_transaction(self) -> bool:
        if self.dialect == "sqlite":
            return bool(self.conn.in_transaction)
        from psycopg.pq import TransactionStatus

        return self.conn.info.transaction_status != TransactionStatus.IDLE

    def _begin(self, write: bool) -> None:
        if self.dialect == "sqlite":
            self.conn.execute("BEGIN IMMEDIATE" if write else "BEGIN")
        elif write:
            self.conn.execute("BEGIN")
        else:
            self.conn.execute("BEGIN ISOLATION LEVEL REPEATABLE READ READ ONLY")

    def _rollback(self) -> None:
        try:
            if self._in_transaction():
                self.conn.execute("ROLLBACK")
        except Exception:  # the connection may be gone; the server rolls back
            logger.debug("rollback failed on %s", self.description, exc_info=True)

    def check_usable(self) -> None:
        if self.closed:
            raise HistoryError(f"history store {self.description} is closed")
        if os.getpid() != self.pid:
            raise HistoryError(
                f"history store {self.description} was opened in process {self.pid} and "
                f"used in process {os.getpid()}; open the store in each process"
            )

    def run(self, fn: Callable[[Tx], T], *, write: bool) -> T:
        """Run ``fn(tx)`` in one transaction; retry it whole on lock contention.

        A write transaction takes the writer lock first (SQLite ``BEGIN
        IMMEDIATE``); a read transaction sees one consistent snapshot. On a
        transient failure the transaction is rolled back and run again after a
        jittered exponential backoff (10 ms doubling to 1 s), until
        ``self.timeout`` seconds have passed; then :class:`StoreBusyError`.
        Any other database error is raised as :class:`HistoryError`; errors
        raised by ``fn`` itself roll back and propagate unchanged.
        """
        self.check_usable()
        db_errors = self._db_error_types()
        deadline = time.monotonic() + self.timeout
        delay = 0.01
        attempt = 0
        while True:
            try:
                self._begin(write)
                out = fn(self.tx)
                self.conn.execute("COMMIT")
                return out
            except BaseException as exc:
                self._rollback()
                if not isinstance(exc, db_errors):
                    raise
                if not self._transient(exc):
                    raise HistoryError(f"{self.description}: {exc}") from exc
                attempt += 1
                if time.monotonic() + delay > deadline:
                    raise StoreBusyError(
                        f"{self.description}: still locked after {attempt} attempts in "
                        f"{self.timeout:g} s ({exc}); another process holds it"
                    ) from exc
                logger.debug("%s busy (%s); retry %d", self.description, exc, attempt)
                time.sleep(delay * random.uniform(0.5, 1.5))  # jitter spreads the retries
                delay = min(2.0 * delay, 1.0)

    def user_tables(self, tx: Tx) -> set[str]:
        if self.dialect == "sqlite":
            rows = tx.all(
                "SELECT name FROM sqlite_master WHERE type = 'table' AND name NOT LIKE 'sqlite_%'"
            )
        else:
            rows = tx.all(
                "SELECT table_name FROM information_schema.tables WHERE table_schema = ?",
                (self.schema,),
            )
        return {r[0] for r in rows}

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            if os.getpid() == self.pid:
                self._rollback()
                self.conn.close()


def _connect_sqlite(path: str, *, timeout: float, create: bool) -> Backend:
    if path != ":memory:":
        if os.path.isdir(path):
            raise HistoryError(f"history store {path!r} is a folder; expected a file")
        if not create and not os.path.exists(path):
            raise HistoryError(
                f"no history store at {path!r} (give --store PATH_OR_URL or set MAGLEVID_HISTORY)"
            )
        if os.path.exists(path):
            if not os.path.isfile(path):
                raise HistoryError(
                    f"history store {path!r} is a special file (FIFO, device or socket); "
                    "expected a file"
                )
            _refuse_foreign_sqlite(path)
    try:
        conn = sqlite3.connect(path, timeout=timeout, isolation_level=None)
    except sqlite3.Error as exc:
        raise HistoryError(f"cannot open history store {path!r}: {exc}") from exc
    backend = Backend(conn, "sqlite", path, timeout=timeout, schema=None)
    try:
        conn.execute(f"PRAGMA busy_timeout = {int(timeout * 1000)}")
        conn.execute("PRAGMA foreign_keys = ON")
        # WAL: one writer and many readers at once; the switch itself needs the
        # lock, so it goes through the retrying runner (a no-op when already WAL).
        mode = _pragma_with_retry(backend, "PRAGMA journal_mode = WAL")
        if path != ":memory:" and str(mode).lower() != "wal":
            logger.warning(
                "%s: journal_mode is %s, not WAL (network file system?); concurrent "
                "writers will wait longer",
                path,
                mode,
            )
        conn.execute("PRAGMA synchronous = FULL")
        app_id = conn.execute("PRAGMA application_id").fetchone()[0]
    except sqlite3.DatabaseError as exc:
        conn.close()
        raise SchemaVersionError(
            f"{path!r} is not a maglevid history store (SQLite says: {exc})"
        ) from exc
    except HistoryError:
        conn.close()
        raise
    if app_id not in (0, APPLICATION_ID):
        conn.close()
        raise SchemaVersionError(
            f"{path!r} is an SQLite file of another application (application_id "
            f"{app_id:#x}), not a maglevid history store"
        )
    return backend


def _refuse_foreign_sqlite(path: str) -> None:
    """Refuse a file that is not (or not yet for this version) a maglevid store, read-only.

    Runs before the read-write connection, which switches the journal to WAL
    and so rewrites the file's header: a store maglevid refuses (another
    application's file, foreign tables, a newer schema) must be left
    byte-identical. The file is opened ``immutable`` (no lock, no journal,
    no -wal/-shm files created), which reads the main file only: a store of
    ours whose latest pages are still in its -wal file looks older or
    empty here, never foreign or newer, so it is not refused by mistake.
    """
    with open(path, "rb") as fh:
        head = fh.read(16)
    if head and head != b"SQLite format 3\x00":
        raise SchemaVersionError(
            f"{path!r} is not a maglevid history store (not an SQLite file); it was left unchanged"
        )
    latest = MIGRATIONS[-1].version if MIGRATIONS else 0
    try:
        app_id, tables, version = _read_only_look(path, immutable=True)
    except sqlite3.DatabaseError:
        # immutable=1 assumes nobody writes meanwhile; a concurrent writer of one
        # of our stores can make that read fail. Look again with SQLite's locks.
        try:
            app_id, tables, version = _read_only_look(path, immutable=False)
        except sqlite3.DatabaseError as exc:
            raise SchemaVersionError(
                f"{path!r} is not a maglevid history store (SQLite says: {exc}); "
                "it was opened read-only and left unchanged"
            ) from exc
    if app_id not in (0, APPLICATION_ID):
        raise SchemaVersionError(
            f"{path!r} is an SQLite file of another application (application_id "
            f"{app_id:#x}), not a maglevid history store; it was opened read-only and left "
            "unchanged"
        )
    if tables and version is None:
        raise SchemaVersionError(
            f"{path!r} holds tables {sorted(tables)} but no schema_migrations table: it is "
            "not a maglevid history store (opened read-only and left unchanged); use another "
            "file"
        )
    if version is not None and int(version) > latest:
        raise SchemaVersionError(
            f"history store {path!r} has schema version {int(version)}, newer than this "
            f"maglevid understands ({latest}); upgrade maglevid to open it (it was opened "
            "read-only and left unchanged)"
        )


def _read_only_look(path: str, *, immutable: bool) -> tuple[int, set[str], int | None]:
    """``(application_id, user tables, schema version)`` of an SQLite file, read-only."""
    uri = "file:" + urllib.parse.quote(os.path.abspath(path)) + "?mode=ro"
    if immutable:
        uri += "&immutable=1"
    try:
        conn = sqlite3.connect(uri, uri=True, isolation_level=None)
    except sqlite3.Error as exc:
        raise HistoryError(f"cannot open history store {path!r}: {exc}") from exc
    try:
        app_id = int(conn.execute("PRAGMA application_id").fetchone()[0])
        tables = {
            r[0]
            for r in conn.execute(
                "SELECT name FROM sqlite_master WHERE type = 'table' AND name NOT LIKE 'sqlite_%'"
            )
        }
        version = (
            conn.execute("SELECT MAX(version) FROM schema_migrations").fetchone()[0]
            if "schema_migrations" in tables
            else None
        )
    finally:
        conn.close()
    return app_id, tables, None if version is None else int(version)


def _pragma_with_retry(backend: Backend, pragma: str) -> Any:
    deadline = time.monotonic() + backend.timeout
    delay = 0.01
    while True:
        try:
            return backend.conn.execute(pragma).fetchone()[0]
        except sqlite3.OperationalError as exc:
            if not backend._transient(exc) or time.monotonic() > deadline:
                raise
            time.sleep(delay * random.uniform(0.5, 1.5))
            delay = min(2.0 * delay, 1.0)


def _connect_postgres(url: str, *, timeout: float, schema: str | None) -> Backend:
    schema = DEFAULT_PG_SCHEMA if schema is None else schema
    if not isinstance(schema, str) or not _SCHEMA_NAME.match(schema):
        raise HistoryError(
            f"schema must be a PostgreSQL identifier (letters, digits, _; at most 63); "
            f"got {schema!r}"
        )
    try:
        import psycopg
    except ImportError as exc:  # pragma: no cover - psycopg is in the fleet extra
        raise HistoryError(
            "a PostgreSQL history store needs psycopg 3: pip install 'maglevid[fleet]'"
        ) from exc
    shown = redact_url(url)
    try:
        conn = psycopg.connect(
            url,
            autocommit=True,
            connect_timeout=max(1, round(timeout)),
            application_name="maglevid",
        )
    except psycopg.Error as exc:
        raise HistoryError(f"cannot connect to {shown}: {exc}".strip()) from exc
    try:
        # Session-wide; the schema itself is created (under a lock) by migrate().
        conn.execute(f'SET search_path TO "{schema}"')  # schema checked by regex above
        conn.execute(f"SET lock_timeout = {int(timeout * 1000)}")
    except psycopg.Error as exc:
        conn.close()
        raise HistoryError(f"{shown}: {exc}") from exc
    return Backend(
        conn, "postgresql", f"{shown} (schema {schema})", timeout=timeout, schema=schema
    )


def connect(
    target: str | os.PathLike[str], *, timeout: float, create: bool, schema: str | None
) -> Backend:
    """Open a connection to the store at ``target`` (no migration)."""
    dialect, location = parse_target(target)
    if dialect == "sqlite":
        if schema is not None:
            raise HistoryError(f"schema={schema!r} applies to PostgreSQL stores only")
        return _connect_sqlite(location, timeout=timeout, create=create)
    return _connect_postgres(location, timeout=timeout, schema=schema)


def _schema_version(backend: Backend, tx: Tx) -> int | None:
    """Applied schema version; ``None`` for an empty store; raises on a foreign one."""
    tables = backend.user_tables(tx)
    if "schema_migrations" not in tables:
        if tables:
            where = (
                backend.description
                if backend.dialect == "sqlite"
                else f"schema {backend.schema!r} of {backend.description}"
            )
            raise SchemaVersionError(
                f"{where} holds tables {sorted(tables)} but no schema_migrations table: "
                "it is not a maglevid history store; use another file or schema"
            )
        return None
    return int(tx.one("SELECT MAX(version) FROM schema_migrations") or 0)


def migrate(backend: Backend, migrations: Sequence[Migration] = MIGRATIONS) -> tuple[int, int]:
    """Bring the store to the last of ``migrations``; returns ``(old, new)`` versions.

    A store at the latest version costs one read transaction. Otherwise all
    missing migrations run in ONE write transaction (both dialects have
    transactional DDL), so a failure leaves the store exactly as it was. A
    store newer than ``migrations`` raises :class:`SchemaVersionError`.
    """
    versions = [m.version for m in migrations]
    if versions != list(range(1, len(versions) + 1)):
        raise ValueError(f"migration versions must be 1, 2, ... without gaps; got {versions}")
    latest = versions[-1] if versions else 0

    def too_new(found: int) -> SchemaVersionError:
        return SchemaVersionError(
            f"history store {backend.description} has schema version {found}, newer than "
            f"this maglevid understands ({latest}); upgrade maglevid to open it"
        )

    def read_version(tx: Tx) -> int | None:
        if backend.dialect == "postgresql" and not tx.one(
            "SELECT count(*) FROM information_schema.schemata WHERE schema_name = ?",
            (backend.schema,),
        ):
            return None
        return _schema_version(backend, tx)

    current = backend.run(read_version, write=False)
    if current is not None and current > latest:
        raise too_new(current)
    if current == latest:
        return latest, latest

    def work(tx: Tx) -> int:
        if backend.dialect == "postgresql":
            # Serialise concurrent first openings of the same schema.
            tx.execute(
                "SELECT pg_advisory_xact_lock(hashtext(?))", (f"maglevid:{backend.schema}",)
            )
            tx.execute(f'CREATE SCHEMA IF NOT EXISTS "{backend.schema}"')
        found = _schema_version(backend, tx)  # again, under the writer lock
        found = 0 if found is None else found
        if found > latest:
            raise too_new(found)
        if found == 0 and backend.dialect == "sqlite":
            tx.execute(f"PRAGMA application_id = {APPLICATION_ID}")
        tx.execute(render(VERSION_TABLE, backend.dialect))
        now = tx.ts_in(datetime.now(timezone.utc))
        for m in migrations:
            if m.version <= found:
                continue
            logger.info(
                "%s: migrating to schema %d (%s)", backend.description, m.version, m.description
            )
            for statement in m.statements:
                tx.execute(render(statement, backend.dialect))
            tx.execute(
                "INSERT INTO schema_migrations (version, description, applied_at) "
                "VALUES (?, ?, ?)",
                (m.version, m.description, now),
            )
        return found

    old = backend.run(work, write=True)
    return old, latest
