#!/usr/bin/env bash
# Throwaway PostgreSQL server for the `postgres`-marked tests.
#
#   source .ci/postgres.sh      # from bash: exports MAGLEVID_TEST_POSTGRES_URL
#
# Installs the Debian `postgresql` package when no server binaries are found
# (needs root and apt), starts a private cluster in a temporary folder on a
# free local port (as the `postgres` user when run as root, since initdb
# refuses root), creates one database, exports MAGLEVID_TEST_POSTGRES_URL and
# stops the server and removes the folder when the sourcing shell exits.
#
# If any step fails it says why on stderr. In CI (CI=true) or with
# MAGLEVID_REQUIRE_POSTGRES=1 the failure is fatal: the sourcing shell exits 1,
# so a CI run can never pass with the PostgreSQL tests skipped. Elsewhere (a
# developer's machine without root) it returns non-zero without exporting the
# URL and the postgres tests skip with a reason (tests/conftest.py turns those
# skips into failures when CI=true).

_maglevid_pg_required() {
    [ "${MAGLEVID_REQUIRE_POSTGRES:-0}" = "1" ] || [ "${CI:-}" = "true" ]
}

_maglevid_pg_fail() {
    echo "postgres.sh: $*" >&2
    if _maglevid_pg_required; then
        echo "postgres.sh: PostgreSQL is required here (CI=true or MAGLEVID_REQUIRE_POSTGRES=1); stopping" >&2
        exit 1
    fi
    echo "postgres.sh: continuing without PostgreSQL; the postgres tests will skip" >&2
    return 1
}

_maglevid_pg_bindir() {
    # MAGLEVID_PG_ROOT: where the server packages live (tests point it elsewhere).
    { ls -d "${MAGLEVID_PG_ROOT:-/usr/lib/postgresql}"/*/bin 2>/dev/null || true; } | sort -V | tail -n 1
}

_maglevid_pg_start() {
    local bindir run_as tmp port
    bindir="$(_maglevid_pg_bindir)"
    if [ -z "$bindir" ] || [ ! -x "$bindir/initdb" ]; then
        if [ "$(id -u)" != "0" ] || ! command -v apt-get >/dev/null 2>&1; then
            _maglevid_pg_fail "no PostgreSQL under /usr/lib/postgresql and cannot apt-get install (need root and apt)"
            return 1
        fi
        echo "postgres.sh: installing postgresql with apt-get" >&2
        export DEBIAN_FRONTEND=noninteractive
        # We start our own cluster: the package need not create (and start) "main".
        mkdir -p /etc/postgresql-common/createcluster.d
        echo "create_main_cluster = false" >/etc/postgresql-common/createcluster.d/maglevid-ci.conf
        apt-get update -qq >/dev/null \
            || { _maglevid_pg_fail "apt-get update failed"; return 1; }
        apt-get install -y -qq --no-install-recommends postgresql >/dev/null \
            || { _maglevid_pg_fail "apt-get install postgresql failed"; return 1; }
        bindir="$(_maglevid_pg_bindir)"
        if [ -z "$bindir" ] || [ ! -x "$bindir/initdb" ]; then
            _maglevid_pg_fail "postgresql installed but no initdb under /usr/lib/postgresql/*/bin"
            return 1
        fi
    fi

    # initdb and postgres refuse to run as root: use the package's system user.
    run_as=()
    if [ "$(id -u)" = "0" ]; then
        if ! id postgres >/dev/null 2>&1; then
            _maglevid_pg_fail "running as root but there is no 'postgres' user"
            return 1
        fi
        run_as=(runuser -u postgres --)
    fi

    tmp="$(mktemp -d "${TMPDIR:-/tmp}/maglevid-pg.XXXXXX")" \
        || { _maglevid_pg_fail "mktemp failed"; return 1; }
    if [ "$(id -u)" = "0" ]; then
        chown postgres: "$tmp"
    fi
    # A free port: bind port 0 and let the kernel choose (tiny race with other users).
    port="$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])' 2>/dev/null)" \
        || port=$((20000 + RANDOM % 20000))

    if ! "${run_as[@]}" "$bindir/initdb" -D "$tmp/data" -U postgres -A trust -E UTF8 \
        --no-locale --no-sync >"$tmp/initdb.log" 2>&1; then
        cat "$tmp/initdb.log" >&2
        rm -rf "$tmp"
        _maglevid_pg_fail "initdb failed"
        return 1
    fi
    # Socket in the temp folder (the system one may not exist); TCP on localhost only.
    # fsync=off: a throwaway cluster, no need to survive an OS crash.
    if ! "${run_as[@]}" "$bindir/pg_ctl" -D "$tmp/data" -l "$tmp/server.log" -w -t 60 \
        -o "-p $port -k $tmp -c listen_addresses=127.0.0.1 -c fsync=off -c max_connections=50" \
        start >/dev/null; then
        cat "$tmp/server.log" >&2 || true
        rm -rf "$tmp"
        _maglevid_pg_fail "pg_ctl start failed on port $port"
        return 1
    fi
    MAGLEVID_PG_TMP="$tmp"
    MAGLEVID_PG_STOP=("${run_as[@]}" "$bindir/pg_ctl" -D "$tmp/data" -m fast -w stop)
    # Stop on any exit of the sourcing shell; INT/TERM exit so the EXIT trap runs.
    trap '_maglevid_pg_stop' EXIT
    trap 'exit 130' INT
    trap 'exit 143' TERM
    if ! "${run_as[@]}" "$bindir/createdb" -h 127.0.0.1 -p "$port" -U postgres maglevid_test; then
        _maglevid_pg_fail "createdb failed"
        return 1
    fi
    export MAGLEVID_TEST_POSTGRES_URL="postgresql://postgres@127.0.0.1:$port/maglevid_test"
    echo "postgres.sh: PostgreSQL $("$bindir/postgres" --version | awk '{print $3}') at $MAGLEVID_TEST_POSTGRES_URL" >&2
}

_maglevid_pg_stop() {
    if [ -n "${MAGLEVID_PG_TMP:-}" ]; then
        "${MAGLEVID_PG_STOP[@]}" >/dev/null 2>&1 || true
        rm -rf "$MAGLEVID_PG_TMP"
        MAGLEVID_PG_TMP=""
    fi
}

# Not `|| true`: a failure already exited above when PostgreSQL is required;
# otherwise the status is reported and the caller's shell continues.
if ! _maglevid_pg_start; then
    if _maglevid_pg_required; then
        echo "postgres.sh: PostgreSQL did not start; stopping" >&2
        exit 1
    fi
fi
