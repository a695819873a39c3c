#!/usr/bin/env bash
# A distributed scene on emulated hosts (deploy/netns/hosts.sh): one machine, four network namespaces.
#
#   h1  broker host   uwsimnet router (hub) + `uwsimnet run SCENE --clock realtime` (client of it)
#   h2  robot1        uwsimnet router -> h1, `gli send` from modem r1-m (broadcast, --wait)
#   h3  robot2        uwsimnet router -> h1, `gli listen r2-m`
#   h4  driver host   uwsimnet router -> h1, `gli listen b-m` (the modem a real driver would take over)
#
#   run-scene.sh [OUTDIR]     default: a temporary folder, removed on success (KEEP=1 keeps it)
#
# Every host writes its logs to OUTDIR/h<i>/ (router.log, broker.log + trace.jsonl, app.log, rx.jsonl);
# on failure they are printed.  Always tears the hosts down.  Exit 0 and a line "run-scene: ok ..." when
# every frame sent in h2 arrived in h3 and h4 and the broker's trace holds them.
# Environment: P (prefix, default "uwr"), NET (default 10.78.0), PY, FRAMES (default 5), INTERVAL (0.3 s),
# TLS=1: the routers and every client log in as in docs/deployment.md (inventory, certificates, mutual
# TLS, usrpwd, ACL roles: broker on h1, an app identity per robot/driver host), else plain TCP.
# FAULT=linkcut: then robot2's link (h3 eth0) goes down for CUT s (default 12, longer than the 10 s lease)
# while robot1 sends; prints when robot2's app saw the modem go (kind None) and come back (sim).
set -euo pipefail

HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
ROOT=$(cd "$HERE/../.." && pwd)
export P=${P:-uwr}
export NET=${NET:-10.78.0}
export PY=${PY:-$ROOT/.venv/bin/python}
FRAMES=${FRAMES:-5}
INTERVAL=${INTERVAL:-0.3}
PORT=7447
WORLD=dist
HOSTS="$HERE/hosts.sh"

OUT=${1:-}
TMP_OUT=0
if [ -z "$OUT" ]; then OUT=$(mktemp -d); TMP_OUT=1; fi
mkdir -p "$OUT"/h1 "$OUT"/h2 "$OUT"/h3 "$OUT"/h4
OK=0

show_logs() {
    local f
    for f in "$OUT"/h*/*.log "$OUT"/h*/*.jsonl; do
        [ -e "$f" ] || continue
        echo "===== $f (last 40 lines)"
        tail -n 40 "$f"
    done
}

cleanup() {
    local rc=$?
    set +e
    trap - INT TERM
    [ "$OK" = 1 ] || { echo "run-scene: FAILED (rc $rc); logs in $OUT" >&2; show_logs >&2; }
    "$HOSTS" down >/dev/null 2>&1 || true          # kills everything started inside the hosts
    if [ "$TMP_OUT" = 1 ] && [ "$OK" = 1 ] && [ "${KEEP:-0}" != 1 ]; then rm -rf "$OUT"; fi
}
trap cleanup EXIT
trap 'exit 130' INT TERM

fail() { echo "run-scene: $*" >&2; exit 1; }
in_host() { local i=$1; shift; ip netns exec "$P-h$i" "$@"; }
wait_for() {   # FILE TEXT SECONDS
    local f=$1 text=$2 n
    n=$(awk "BEGIN{print int($3 * 10)}")
    for _ in $(seq 1 "$n"); do
        grep -q "$text" "$f" 2>/dev/null && return 0
        sleep 0.1
    done
    fail "no '$text' in $f after $3 s"
}

"$HOSTS" up 4

cat >"$OUT/scene.xml" <<EOF
<?xml version="1.0"?>
<UWSimScene>
  <simulation><seed>1</seed><clock>realtime</clock><world>$WORLD</world></simulation>
  <CustomCommsChannel><id>0</id><propTimeIncPerMeter>0.6667</propTimeIncPerMeter></CustomCommsChannel>
  <vehicle><name>robot1</name><position>0 0 0</position><CustomCommsDevice><dccommsId>r1-m</dccommsId>
    <mac>1</mac><txChannelId>0</txChannelId><rxChannelId>0</rxChannelId><bitrate>10000</bitrate>
    <txFifoSize>4000</txFifoSize></CustomCommsDevice></vehicle>
  <vehicle><name>robot2</name><position>150 0 0</position><CustomCommsDevice><dccommsId>r2-m</dccommsId>
    <mac>2</mac><txChannelId>0</txChannelId><rxChannelId>0</rxChannelId><bitrate>10000</bitrate>
    <txFifoSize>4000</txFifoSize></CustomCommsDevice></vehicle>
  <vehicle><name>buoy</name><position>0 300 0</position><CustomCommsDevice><dccommsId>b-m</dccommsId>
    <mac>3</mac><txChannelId>0</txChannelId><rxChannelId>0</rxChannelId><bitrate>10000</bitrate>
    <txFifoSize>4000</txFifoSize></CustomCommsDevice></vehicle>
</UWSimScene>
EOF

cd "$ROOT"
export PYTHONUNBUFFERED=1 RUST_LOG=${RUST_LOG:-error}
if [ "${TLS:-0}" = 1 ]; then
    # the deployment of docs/deployment.md: inventory -> certificates -> router and client configurations
    {
        echo "world = \"$WORLD\""
        echo "topology = \"star\""
        echo "hub = \"h1\""
        echo "tls_dir = \"$OUT/tls\""
        echo "etc_dir = \"$OUT/etc/{host}\""
        for i in 1 2 3 4; do
            printf '[hosts.h%s]\naddress = "%s"\nlisten = ["tls/0.0.0.0:%s"]\n' "$i" "$NET.$i" "$PORT"
        done
        printf '[[identities]]\nname = "brk"\nrole = "broker"\nhost = "h1"\n'
        for i in 2 3 4; do printf '[[identities]]\nname = "app%s"\nrole = "app"\nhost = "h%s"\n' "$i" "$i"; done
    } >"$OUT/inventory.toml"
    eval "$("$PY" -m uwsimnet_zenoh.cli deploy certs "$OUT/inventory.toml" "$OUT/tls")" >/dev/null
    "$PY" -m uwsimnet_zenoh.cli deploy render "$OUT/inventory.toml" -o "$OUT/etc" >/dev/null
    # routers: `uwsimnet router --config` (the file's TLS endpoints, mutual TLS, usrpwd, ACL)
    for i in 1 2 3 4; do                # the hub first: the others connect to it at once
        in_host "$i" "$PY" -m uwsimnet_zenoh.cli router --config "$OUT/etc/h$i/router.json5" \
            >"$OUT/h$i/router.log" 2>&1 </dev/null &
        [ "$i" != 1 ] || wait_for "$OUT/h1/router.log" "listening on" 15
    done
    BROKER_LOGIN=(--zenoh-config "$OUT/etc/h1/clients/brk.json5")
else
    # routers: a star around h1, plain TCP
    in_host 1 "$PY" -m uwsimnet_zenoh.cli router --listen "tcp/0.0.0.0:$PORT" >"$OUT/h1/router.log" 2>&1 </dev/null &
    wait_for "$OUT/h1/router.log" "listening on" 15
    for i in 2 3 4; do
        in_host "$i" "$PY" -m uwsimnet_zenoh.cli router --listen "tcp/0.0.0.0:$PORT" --connect "tcp/$NET.1:$PORT" \
            >"$OUT/h$i/router.log" 2>&1 </dev/null &
    done
    BROKER_LOGIN=(--connect "tcp/127.0.0.1:$PORT")
fi
for i in 1 2 3 4; do wait_for "$OUT/h$i/router.log" "listening on" 15; done
# an app in host I: `gli` logged in as that host's identity (TLS=1) or a plain client of the local router
login() { if [ "${TLS:-0}" = 1 ]; then echo "$OUT/etc/h$1/clients/app$1.json5"; else echo -; fi; }
gli() {
    local i=$1; shift
    if [ "${TLS:-0}" = 1 ]; then
        in_host "$i" "$PY" -m uwsimnet_gli.cli --zenoh-config "$(login "$i")" -w "$WORLD" "$@"
    else
        in_host "$i" "$PY" -m uwsimnet_gli.cli -e "tcp/127.0.0.1:$PORT" -w "$WORLD" "$@"
    fi
}

# the broker on h1, a client of its local router
# (`ip netns exec` forks and does not pass signals on: the broker's own pid goes to broker.pid)
in_host 1 sh -c 'echo $$ >"$0"; exec "$@"' "$OUT/h1/broker.pid" "$PY" -m uwsimnet_zenoh.cli run \
    "$OUT/scene.xml" "${BROKER_LOGIN[@]}" --trace "$OUT/h1/trace.jsonl" \
    >"$OUT/h1/broker.log" 2>&1 </dev/null &
wait_for "$OUT/h1/broker.log" "uwsimnet: running" 20

# robot2 and the driver host listen (each through its own router, two hops from the broker)
TIMEOUT=$(awk "BEGIN{print int($FRAMES * $INTERVAL + 20)}")
gli 3 listen r2-m --count "$FRAMES" --timeout "$TIMEOUT" --json \
    >"$OUT/h3/rx.jsonl" 2>"$OUT/h3/app.log" </dev/null &
L3=$!
gli 4 listen b-m --count "$FRAMES" --timeout "$TIMEOUT" --json \
    >"$OUT/h4/rx.jsonl" 2>"$OUT/h4/app.log" </dev/null &
L4=$!
# both listeners' subscriptions must reach h1 before the first frame: check the modem kinds from h2
# (a round trip h2 -> h1 -> h2), then give the subscriptions of h3/h4 the same time to propagate
for try in $(seq 1 10); do                  # (routers may still be connecting to the hub)
    gli 2 info >"$OUT/h2/info.log" 2>&1 && break
    [ "$try" -lt 10 ] || fail "gli info from h2 failed"
    sleep 0.5
done
sleep 1
gli 2 send r1-m 255 "hello from robot1" --count "$FRAMES" --interval "$INTERVAL" --wait \
    >"$OUT/h2/app.log" 2>&1 </dev/null || fail "gli send in h2 failed"
wait "$L3" || fail "listener in h3 (robot2) ended with an error"
wait "$L4" || fail "listener in h4 (driver host) ended with an error"
SENT=$FRAMES
if [ "${FAULT:-}" = linkcut ]; then
    # robot2's link cut longer than the Zenoh lease (10 s): what robot2's app sees, then reconnection
    CUT=${CUT:-12}
    in_host 3 "$PY" "$HERE/watch_kind.py" "$(login 3)" "tcp/127.0.0.1:$PORT" "$WORLD" r2-m "$(awk "BEGIN{print $CUT + 20}")" \
        >"$OUT/h3/kind.log" 2>&1 </dev/null &
    wait_for "$OUT/h3/kind.log" "sim (start)" 15
    gli 3 listen r2-m --count 1 --timeout "$(awk "BEGIN{print $CUT + 25}")" --json \
        >"$OUT/h3/rx-after.jsonl" 2>>"$OUT/h3/app.log" </dev/null &
    L3=$!
    sleep 1
    t_cut=$(date +%s.%N)
    ip -n "$P-h3" link set eth0 down
    echo "$t_cut link down" >>"$OUT/h3/link.log"
    sleep 1
    gli 2 send r1-m 255 "during the cut" --count 3 --interval 0.3 --wait \
        >>"$OUT/h2/app.log" 2>&1 </dev/null || fail "gli send during the cut failed"
    sleep "$(awk "BEGIN{print $CUT - 2}")"
    t_up=$(date +%s.%N)
    ip -n "$P-h3" link set eth0 up
    echo "$t_up link up" >>"$OUT/h3/link.log"
    SENT=$((SENT + 3))
    # resend until robot2 hears one (what is sent before the routers have reconnected is lost)
    for _ in $(seq 1 30); do
        kill -0 "$L3" 2>/dev/null || break
        gli 2 send r1-m 255 "after the cut" >>"$OUT/h2/app.log" 2>&1 </dev/null || true
        SENT=$((SENT + 1))
        sleep 0.5
    done
    wait "$L3" || fail "robot2 (h3) heard nothing after the link came back"
    t_none=$(awk '$2 == "None" {print $1; exit}' "$OUT/h3/kind.log")
    t_sim=$(awk -v up="$t_up" '$2 == "sim" && $1 > up {print $1; exit}' "$OUT/h3/kind.log")
    [ -n "$t_none" ] || fail "robot2's app never saw r2-m lose its simulator (kind None) during the cut"
    [ -n "$t_sim" ] || fail "robot2's app never saw r2-m served again (kind sim) after the cut"
    echo "linkcut: r2-m kind None $(awk "BEGIN{printf \"%.2f\", $t_none - $t_cut}") s after the cut," \
         "sim again $(awk "BEGIN{printf \"%.2f\", $t_sim - $t_up}") s after the link came back"
fi

# SIGTERM (SIGINT is ignored by a script's background jobs): the broker stops, prints its summary
kill -TERM "$(cat "$OUT/h1/broker.pid")" 2>/dev/null || true
wait_for "$OUT/h1/broker.log" "^trace: " 20

n3=$(grep -c '"src": 1' "$OUT/h3/rx.jsonl" || true)
n4=$(grep -c '"src": 1' "$OUT/h4/rx.jsonl" || true)
[ "$n3" = "$FRAMES" ] || fail "robot2 (h3) got $n3 of $FRAMES frames"
[ "$n4" = "$FRAMES" ] || fail "driver host (h4) got $n4 of $FRAMES frames"
"$PY" -m uwsimnet_zenoh.cli report "$OUT/h1/trace.jsonl" >"$OUT/h1/report.log" 2>&1 || fail "report failed"
"$PY" - "$OUT/h1/trace.jsonl" "$SENT" <<'EOF' || fail "trace check failed"
import sys
from uwsimnet_zenoh.analysis import analyse, read_trace
path, n = sys.argv[1], int(sys.argv[2])
ev = list(read_trace(path)[1])
rx = sorted(e["dev"] for e in ev if e["ev"] == "rx")
assert sum(e["ev"] == "enq" for e in ev) == n, "enq"
assert rx == sorted(["b-m", "r2-m"] * n), rx      # the simulator delivered all (Zenoh lost some on the way)
a = analyse(path, horizon=5.0)
assert a.conservation.ok, a.conservation.violations[:5]
print(f"trace: {n} enq, {len(rx)} rx, conservation ok")
EOF
OK=1
echo "run-scene: ok: $FRAMES frames from robot1 (h2) reached robot2 (h3) and the driver host (h4) through" \
     "the broker on h1 (4 routers, $([ "${TLS:-0}" = 1 ] && echo "mutual TLS + usrpwd + ACL" || echo "plain TCP"));" \
     "logs in $OUT"
