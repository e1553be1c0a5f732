#!/usr/bin/env bash
# Three hosts on one machine (docs/deployment.md): the network namespaces hr_robot, hr_compute
# and hr_operator, each with one interface (eth0) on a veth pair whose other end is a port of
# the bridge hr_br0 -- a small switched LAN, 10.231.0.0/24:
#
#   hr_robot    10.231.0.1   joint_driver, scene_sim, voxel_mapper, marker_localizer, reach_executor
#   hr_compute  10.231.0.2   reach_planner
#   hr_operator 10.231.0.3   reach_operator, a recorder
#
# Each link is capped in both directions with tc tbf (netem, for delay and loss, is used only
# where the kernel has it: --delay / --loss). Needs root (CI runs as root).
#
#   tools/hosts.sh up [--rate RATE] [--operator-rate RATE] [--delay MS] [--loss PCT]
#   tools/hosts.sh down
#   tools/hosts.sh status
#   tools/hosts.sh cut HOST SECONDS      # the host's link down for SECONDS, then up again
#   tools/hosts.sh link HOST down|up     # the host's link down (or up) until told otherwise
#   tools/hosts.sh exec HOST CMD ...     # CMD on HOST, discovery across the LAN (SUBNET)
#
# RATE as tc takes it (default 1gbit; the operator's link 20mbit, a good wireless link).
set -euo pipefail

HOSTS=(robot compute operator)
declare -A ADDR=([robot]=10.231.0.1 [compute]=10.231.0.2 [operator]=10.231.0.3)
BRIDGE=hr_br0
PREFIX=24

die() { echo "hosts.sh: $*" >&2; exit 1; }
ns() { echo "hr_$1"; }
port() { echo "hr_$1_br"; }          # the bridge's end of the host's link
known_host() { [[ -n "${ADDR[$1]:-}" ]] || die "unknown host '$1' (one of: ${HOSTS[*]})"; }

need_root() {
    [[ $(id -u) == 0 ]] || die "needs root (network namespaces, veth, tc): run it as root or with sudo"
    command -v ip >/dev/null || die "'ip' (iproute2) not found"
    command -v tc >/dev/null || die "'tc' (iproute2) not found"
}

shape() {   # shape DEV [NETNS]: tbf at RATE, netem in front where asked and available
    local dev=$1 where=${2:-} rate=$3
    local tcn=(tc); [[ -n $where ]] && tcn=(ip netns exec "$where" tc)
    if [[ -n $DELAY || -n $LOSS ]]; then
        local args=(); [[ -n $DELAY ]] && args+=(delay "${DELAY}ms"); [[ -n $LOSS ]] && args+=(loss "${LOSS}%")
        if "${tcn[@]}" qdisc add dev "$dev" root handle 1: netem "${args[@]}" 2>/dev/null; then
            "${tcn[@]}" qdisc add dev "$dev" parent 1:1 handle 10: tbf rate "$rate" burst 64kb latency 100ms
            return
        fi
        echo "hosts.sh: netem is not available in this kernel: no delay/loss on $dev (rate cap only)" >&2
    fi
    "${tcn[@]}" qdisc add dev "$dev" root tbf rate "$rate" burst 64kb latency 100ms
}

up() {
    RATE=1gbit; OPERATOR_RATE=20mbit; DELAY=""; LOSS=""
    while [[ $# -gt 0 ]]; do
        case $1 in
            --rate) RATE=${2:?--rate needs a value}; shift 2 ;;
            --operator-rate) OPERATOR_RATE=${2:?--operator-rate needs a value}; shift 2 ;;
            --delay) DELAY=${2:?--delay needs milliseconds}; shift 2 ;;
            --loss) LOSS=${2:?--loss needs a percentage}; shift 2 ;;
            *) die "up: unknown option '$1'" ;;
        esac
    done
    need_root
    ip link show "$BRIDGE" >/dev/null 2>&1 && die "already up ($BRIDGE exists): 'tools/hosts.sh down' first"
    ip link add "$BRIDGE" type bridge mcast_snooping 0      # discovery's multicast reaches every port
    ip link set "$BRIDGE" up
    for h in "${HOSTS[@]}"; do
        local n; n=$(ns "$h")
        ip netns add "$n"
        ip link add "$(port "$h")" type veth peer name eth0 netns "$n"
        ip link set "$(port "$h")" master "$BRIDGE" up
        ip -n "$n" link set lo up
        ip -n "$n" addr add "${ADDR[$h]}/$PREFIX" dev eth0
        ip -n "$n" link set eth0 up
        ip -n "$n" route add 224.0.0.0/4 dev eth0           # SPDP multicast out of eth0
        local r=$RATE; [[ $h == operator ]] && r=$OPERATOR_RATE
        shape "$(port "$h")" "" "$r"            # towards the host
        shape eth0 "$n" "$r"                    # from the host
        echo "hosts.sh: $n ${ADDR[$h]} on $BRIDGE, link $r each way"
    done
}

down() {
    need_root
    for h in "${HOSTS[@]}"; do
        ip netns del "$(ns "$h")" 2>/dev/null || true      # its eth0 goes, and the veth pair with it
        ip link del "$(port "$h")" 2>/dev/null || true
    done
    ip link del "$BRIDGE" 2>/dev/null || true
    echo "hosts.sh: down"
}

status() {
    ip link show "$BRIDGE" >/dev/null 2>&1 || { echo "hosts.sh: down"; return 1; }
    for h in "${HOSTS[@]}"; do
        local n; n=$(ns "$h")
        local state; state=$(ip -br link show "$(port "$h")" 2>/dev/null | awk '{print $2}')
        local rate; rate=$(tc qdisc show dev "$(port "$h")" 2>/dev/null | grep -o 'rate [^ ]*' | head -1)
        echo "$n ${ADDR[$h]} link ${state:-missing} ${rate:-no cap}"
    done
}

cut() {
    local h=${1:?cut HOST SECONDS} s=${2:?cut HOST SECONDS}
    known_host "$h"; need_root
    [[ $s =~ ^[0-9]+([.][0-9]+)?$ ]] || die "cut: SECONDS must be a number, got '$s'"
    ip link set "$(port "$h")" down
    echo "hosts.sh: $(ns "$h") cut for $s s"
    sleep "$s"
    ip link set "$(port "$h")" up
    echo "hosts.sh: $(ns "$h") back"
}

link() {
    local h=${1:?link HOST up|down} state=${2:?link HOST up|down}
    known_host "$h"; need_root
    [[ $state == up || $state == down ]] || die "link: up or down, got '$state'"
    ip link set "$(port "$h")" "$state"
    echo "hosts.sh: $(ns "$h") link $state"
}

run_on() {
    local h=${1:?exec HOST CMD ...}; shift
    known_host "$h"; need_root
    [[ $# -gt 0 ]] || die "exec: no command"
    ip netns exec "$(ns "$h")" env ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET "$@"
}

case ${1:-} in
    up) shift; up "$@" ;;
    down) down ;;
    status) status ;;
    cut) shift; cut "$@" ;;
    link) shift; link "$@" ;;
    exec) shift; run_on "$@" ;;
    *) die "usage: tools/hosts.sh up [--rate R] [--operator-rate R] [--delay MS] [--loss PCT] | down | status | cut HOST SECONDS | link HOST down|up | exec HOST CMD ..." ;;
esac
