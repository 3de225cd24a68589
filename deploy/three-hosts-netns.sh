#!/bin/sh
# The three-host foyer3 deployment of deploy/README.md on one machine: hosts are network
# namespaces joined by veth pairs, every link is mutual TLS. Runs DURATION seconds, then
# scores the fusion center's live tracks against the simulator's truth (uwbnet eval).
#
#   sudo deploy/three-hosts-netns.sh [DURATION] [WORKDIR]     # three namespaces
#   deploy/three-hosts-netns.sh --single [DURATION] [WORKDIR] # same processes, one host
#
# WORKDIR (default: a new temporary directory) receives certs/, *.toml, logs, net.mcap,
# live.jsonl and eval.json. Everything started is stopped and the namespaces are deleted on
# exit, also on Ctrl-C.
set -eu
single=0
[ "${1:-}" = "--single" ] && { single=1; shift; }
duration=${1:-60}
work=${2:-$(mktemp -d /tmp/uwbnet3.XXXXXX)}
here=$(cd "$(dirname "$0")" && pwd)
uwbnet=${UWBNET:-uwbnet}
tag=u3$$
mkdir -p "$work"
pids=""

cleanup() {
    for p in $pids; do kill -TERM "$p" 2>/dev/null || true; done
    for p in $pids; do wait "$p" 2>/dev/null || true; done
    if [ $single = 0 ]; then
        for h in f a b; do ip netns del "$tag$h" 2>/dev/null || true; done
    fi
}
trap cleanup EXIT INT TERM

run() {  # run HOST NAME ARGS...: start uwbnet on HOST (f, a, b) in the background
    host=$1; name=$2; shift 2
    if [ $single = 1 ]; then
        "$uwbnet" -v "$@" > "$work/$name.out" 2> "$work/$name.err" &
    else
        ip netns exec "$tag$host" "$uwbnet" -v "$@" > "$work/$name.out" 2> "$work/$name.err" &
    fi
    pids="$! $pids"
}

if [ $single = 1 ]; then
    ip_a=127.0.0.1; ip_b=127.0.0.1
else
    ip_a=10.66.1.1; ip_b=10.66.2.1
    for h in f a b; do ip netns add "$tag$h"; ip -n "$tag$h" link set lo up; done
    i=1
    for h in a b; do
        ip link add "$tag$h" type veth peer name "$tag${h}f"
        ip link set "$tag$h" netns "$tag$h"
        ip link set "$tag${h}f" netns "${tag}f"
        ip -n "$tag$h" addr add "10.66.$i.2/24" dev "$tag$h"
        ip -n "${tag}f" addr add "10.66.$i.1/24" dev "$tag${h}f"
        ip -n "$tag$h" link set "$tag$h" up
        ip -n "${tag}f" link set "$tag${h}f" up
        i=$((i + 1))
    done
fi

"$here/make-certs.sh" "$work/certs" fusion hostA hostB recorder > /dev/null
tls() {
    printf '[zenoh.tls]\nca = "%s/ca.pem"\ncert = "%s/%s.pem"\nkey = "%s/%s.key"\n' \
        "$work/certs" "$work/certs" "$1" "$work/certs" "$1"
}
{
    printf 'net = "foyer"\ntracks_jsonl = "%s/live.jsonl"\n' "$work"
    printf '[zenoh]\nmode = "router"\nlisten = ["tls/0.0.0.0:7447"]\nlease = "750 ms"\n'
    tls fusion
    printf '[zenoh.access]\nmembers = ["fusion", "hostA", "hostB", "recorder"]\n'
} > "$work/fusion.toml"
{ printf 'net = "foyer"\n[zenoh]\nmode = "client"\nconnect = ["tls/127.0.0.1:7447"]\n'; tls recorder; } > "$work/recorder.toml"
for h in A B; do
    if [ $h = A ]; then nodes='["bat1", "bat2", "bat3"]'; truth=true; ip=$ip_a
    else nodes='["bat4", "bat5", "bat6"]'; truth=false; ip=$ip_b; fi
    {
        printf 'net = "foyer"\nscenario = "foyer3"\nseed = 1\nnodes = %s\ntruth = %s\n' "$nodes" "$truth"
        printf '[zenoh]\nmode = "client"\nconnect = ["tls/%s:7447"]\nlease = "750 ms"\n' "$ip"
        tls "host$h"
    } > "$work/host$h.toml"
done

run f fusion fusion --config "$work/fusion.toml"
sleep 2
run f record record --config "$work/recorder.toml" --out "$work/net.mcap"
sleep 2
run a hostA simnode --config "$work/hostA.toml"
run b hostB simnode --config "$work/hostB.toml"
sleep "$duration"
cleanup
pids=""
"$uwbnet" eval --truth "$work/net.mcap" --tracks "$work/live.jsonl" | tee "$work/eval.json"
echo "results in $work" >&2
