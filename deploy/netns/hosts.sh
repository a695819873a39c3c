#!/usr/bin/env bash
# Emulated hosts on one Linux machine: network namespaces on a bridge, one Zenoh router in each.
#
#   hosts.sh up N             make hosts 1..N: namespaces $P-h1..$P-hN, address $NET.I/24 on eth0, all on
#                             a bridge that lives in its own namespace $P-sw (nothing changes in the
#                             machine's own namespace: no interface, no address, no route)
#   hosts.sh down             remove every namespace of prefix $P and the processes inside (idempotent)
#   hosts.sh status           list the hosts and their addresses
#   hosts.sh exec I CMD...    run CMD inside host I (e.g. `hosts.sh exec 1 ping -c1 $NET.3`)
#   hosts.sh routers DIR      start one router per host: `uwsimnet router --config DIR/hI/router.json5` in
#                             host I, for every DIR/hI/router.json5 (logs and pid in DIR/hI/)
#   hosts.sh stop-routers DIR stop the routers started from DIR
#   hosts.sh demo [N]         up N hosts (default 3), TLS certificates + configurations for a chain
#                             h1 - h2 - ... - hN, routers, a publisher in h1 and a subscriber in hN, then down
#
# Needs root and iproute2.  Environment: P (namespace prefix, default "uws", at most 8 characters),
# NET (first three octets, default 10.77.0), PORT (router port, default 7447), PY (python with the
# project installed, default the repository's .venv/bin/python).  Part B runs the distributed scene
# (broker host, robot hosts, driver host) on top of these hosts.
set -euo pipefail

P=${P:-uws}
NET=${NET:-10.77.0}
PORT=${PORT:-7447}
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
ROOT=$(cd "$HERE/../.." && pwd)
PY=${PY:-$ROOT/.venv/bin/python}
SW="$P-sw"

die() { echo "hosts.sh: $*" >&2; exit 2; }
host_ns() { echo "$P-h$1"; }
# running (a zombie is not: processes left by an earlier hosts.sh are reaped by init, maybe late)
alive() {
    local st
    st=$(sed 's/.*) //' "/proc/$1/stat" 2>/dev/null | cut -d' ' -f1) || return 1
    [ -n "$st" ] && [ "$st" != Z ] && [ "$st" != X ]
}

preflight() {
    [ "$(id -u)" = 0 ] || die "needs root (network namespaces)"
    command -v ip >/dev/null 2>&1 || die "needs iproute2 (ip)"
    ip netns list >/dev/null 2>&1 || die "'ip netns' does not work here"
    [[ "$P" =~ ^[a-z][a-z0-9]{0,7}$ ]] || die "P must be 1-8 lowercase letters/digits, starting with a letter"
}

our_namespaces() {
    ip netns list 2>/dev/null | awk '{print $1}' | grep -E "^$P-(sw|h[0-9]+)$" || true
}

down() {
    local ns pids
    for ns in $(our_namespaces); do
        pids=$(ip netns pids "$ns" 2>/dev/null || true)
        if [ -n "$pids" ]; then
            # shellcheck disable=SC2086 - one pid per word
            kill $pids 2>/dev/null || true
            for _ in $(seq 1 30); do
                [ -z "$(ip netns pids "$ns" 2>/dev/null || true)" ] && break
                sleep 0.1
            done
            pids=$(ip netns pids "$ns" 2>/dev/null || true)
            # shellcheck disable=SC2086
            [ -z "$pids" ] || kill -9 $pids 2>/dev/null || true
        fi
        ip netns del "$ns" 2>/dev/null || true
    done
}

up() {
    local n=$1 i ns
    [[ "$n" =~ ^[0-9]+$ ]] && [ "$n" -ge 1 ] && [ "$n" -le 250 ] || die "up: N must be 1..250"
    down
    trap 'echo "hosts.sh: up failed, cleaning up" >&2; down' ERR
    trap 'echo "hosts.sh: up interrupted, cleaning up" >&2; down; exit 130' INT TERM
    ip netns add "$SW"
    ip -n "$SW" link set lo up
    ip -n "$SW" link add br0 type bridge
    ip -n "$SW" link set br0 up
    for i in $(seq 1 "$n"); do
        ns=$(host_ns "$i")
        ip netns add "$ns"
        ip link add eth0 netns "$ns" type veth peer name "h$i" netns "$SW"
        ip -n "$SW" link set "h$i" master br0
        ip -n "$SW" link set "h$i" up
        ip -n "$ns" addr add "$NET.$i/24" dev eth0
        ip -n "$ns" link set lo up
        ip -n "$ns" link set eth0 up
    done
    # the bridge (no STP) forwards at once; with ping at hand, check that host 1 reaches host N
    if [ "$n" -gt 1 ] && command -v ping >/dev/null 2>&1; then
        for _ in $(seq 1 50); do
            ip netns exec "$(host_ns 1)" ping -c1 -W1 "$NET.$n" >/dev/null 2>&1 && break
            sleep 0.1
        done
        ip netns exec "$(host_ns 1)" ping -c1 -W1 "$NET.$n" >/dev/null 2>&1 || {
            down; die "up: h1 cannot reach h$n, cleaned up"; }
    fi
    trap - ERR INT TERM
    echo "up: $n hosts ($(host_ns 1)..$(host_ns "$n"), $NET.1..$NET.$n) on bridge br0 in $SW"
}

status() {
    local ns
    for ns in $(our_namespaces); do
        echo "$ns: $(ip -n "$ns" -br -4 addr show 2>/dev/null | awk '$1 != "lo" {print $1, $3}' | tr '\n' ' ')"
    done
}

routers() {
    local dir=$1 conf host i ns started=0
    [ -d "$dir" ] || die "routers: no directory $dir"
    for conf in "$dir"/h*/router.json5; do
        [ -e "$conf" ] || continue
        host=$(basename "$(dirname "$conf")")
        i=${host#h}
        ns=$(host_ns "$i")
        ip netns list | awk '{print $1}' | grep -qx "$ns" || die "routers: host $ns is not up"
        # `uwsimnet router --config` listens on the file's listen/endpoints
        ip netns exec "$ns" "$PY" -m uwsimnet_zenoh.cli router --config "$conf" \
            >"$dir/$host/router.log" 2>&1 </dev/null &
        echo $! >"$dir/$host/router.pid"
        started=$((started + 1))
    done
    [ "$started" -gt 0 ] || die "routers: no $dir/h*/router.json5"
    for conf in "$dir"/h*/router.json5; do
        host=$(basename "$(dirname "$conf")")
        for _ in $(seq 1 100); do
            grep -q "listening on" "$dir/$host/router.log" 2>/dev/null && break
            alive "$(cat "$dir/$host/router.pid")" || die "router of $host exited: $(tail -3 "$dir/$host/router.log")"
            sleep 0.1
        done
        grep -q "listening on" "$dir/$host/router.log" || die "router of $host did not start: $(tail -3 "$dir/$host/router.log")"
        echo "router of $host: $(grep 'listening on' "$dir/$host/router.log")"
    done
}

stop_routers() {
    local dir=$1 pidf pid
    for pidf in "$dir"/h*/router.pid; do
        [ -e "$pidf" ] || continue
        pid=$(cat "$pidf")
        rm -f "$pidf"
        # only the router we started (the pid may have been reused since)
        tr '\0' ' ' <"/proc/$pid/cmdline" 2>/dev/null | grep -q " router --config " || continue
        kill "$pid" 2>/dev/null || true
        for _ in $(seq 1 50); do alive "$pid" || break; sleep 0.1; done
        ! alive "$pid" || kill -9 "$pid" 2>/dev/null || true
    done
}

DEMO_WORK=""
demo_cleanup() {
    if [ -n "$DEMO_WORK" ]; then
        stop_routers "$DEMO_WORK/out" 2>/dev/null || true
        [ "${KEEP:-0}" = 1 ] && echo "demo: kept $DEMO_WORK" || rm -rf "$DEMO_WORK"
    fi
    down
}

demo() {
    local n=${1:-3} work i
    [ "$n" -ge 2 ] || die "demo: N must be at least 2"
    work=$(mktemp -d)
    DEMO_WORK=$work
    trap demo_cleanup EXIT
    trap 'exit 130' INT TERM
    up "$n"
    trap 'exit 130' INT TERM
    {
        echo "world = \"demo\""
        echo "topology = \"chain\""
        echo "tls_dir = \"$work/tls\""
        echo "etc_dir = \"$work/out/{host}\""
        for i in $(seq 1 "$n"); do
            printf '[hosts.h%s]\naddress = "%s"\nport = %s\nlisten = ["tls/0.0.0.0:%s"]\n' "$i" "$NET.$i" "$PORT" "$PORT"
        done
        printf '[[identities]]\nname = "pub"\nrole = "app"\nhost = "h1"\n'
        printf '[[identities]]\nname = "sub"\nrole = "app"\nhost = "h%s"\n' "$n"
    } >"$work/inventory.toml"
    (cd "$ROOT" && eval "$("$PY" -m uwsimnet_zenoh.cli deploy certs "$work/inventory.toml" "$work/tls")") >/dev/null
    (cd "$ROOT" && "$PY" -m uwsimnet_zenoh.cli deploy render "$work/inventory.toml" -o "$work/out") >/dev/null
    routers "$work/out"
    ip netns exec "$(host_ns "$n")" "$PY" "$HERE/pubsub.py" sub "$work/out/h$n/clients/sub.json5" \
        uwsimnet/demo/pose/auv1 3 >"$work/sub.out" 2>&1 &
    local sub=$!
    ip netns exec "$(host_ns 1)" "$PY" "$HERE/pubsub.py" pub "$work/out/h1/clients/pub.json5" \
        uwsimnet/demo/pose/auv1 3 "$work/sub.out"
    if wait "$sub"; then
        cat "$work/sub.out"
        echo "demo: ok, h1 -> h$n across $n routers over mutual TLS"
    else
        cat "$work/sub.out" >&2
        die "demo: the subscriber in h$n did not get the messages from h1"
    fi
}

cmd=${1:-}
[ -n "$cmd" ] || die "usage: $0 up N | down | status | exec I CMD... | routers DIR | stop-routers DIR | demo [N]"
shift
case "$cmd" in
    up) preflight; [ $# -eq 1 ] || die "usage: $0 up N"; up "$1" ;;
    down) preflight; down; echo "down: no namespace of prefix $P left" ;;
    status) preflight; status ;;
    exec) preflight; [ $# -ge 2 ] || die "usage: $0 exec I CMD..."; i=$1; shift; exec ip netns exec "$(host_ns "$i")" "$@" ;;
    routers) preflight; [ $# -eq 1 ] || die "usage: $0 routers DIR"; routers "$1" ;;
    stop-routers) [ $# -eq 1 ] || die "usage: $0 stop-routers DIR"; stop_routers "$1" ;;
    demo) preflight; demo "${1:-3}" ;;
    -h|--help|help) sed -n '2,24p' "$0" | sed 's/^# \{0,1\}//' ;;
    *) die "unknown command $cmd (up, down, status, exec, routers, stop-routers, demo)" ;;
esac
