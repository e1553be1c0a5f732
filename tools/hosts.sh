#!/usr/bin/env bash
# Three hosts on one machine (docs/deployment.md): the network namespaces <P>_robot, <P>_compute
# and <P>_operator, each with one interface (eth0) on a veth pair whose other end is a port of
# the bridge <P>_br -- a small switched LAN, 10.231.0.0/24:
#
#   <P>_robot    10.231.0.1   joint_driver, scene_sim, voxel_mapper, marker_localizer, reach_executor
#   <P>_compute  10.231.0.2   reach_planner
#   <P>_operator 10.231.0.3   reach_operator, a recorder
#
# <P>, the prefix, is $HR_HOSTS_PREFIX, by default "hr" and the uid of the user who ran it
# (sudo's SUDO_UID, else id -u: hr0 for root, hr1000 for uid 1000), so two users on one machine
# get their own namespaces, bridge and LAN. Letters, digits, at most 8 (interface names <= 15).
#
# Each link is capped in both directions with tc tbf (netem, for delay and loss, is used only
# where the kernel has it: --delay / --loss). Needs root (CI runs as root).
#
#   tools/hosts.sh up [--rate RATE] [--operator-rate RATE] [--delay MS] [--loss PCT]
#   tools/hosts.sh down                  # stops every process in the namespaces, then removes them
#   tools/hosts.sh status
#   tools/hosts.sh names                 # "bridge BR", then "HOST NETNS PORT ADDRESS" per host
#   tools/hosts.sh cut HOST SECONDS      # the host's link down for SECONDS, then up again
#   tools/hosts.sh link HOST down|up     # the host's link down (or up) until told otherwise
#   tools/hosts.sh exec HOST CMD ...     # CMD on HOST, discovery across the LAN (SUBNET)
#
# RATE as tc takes it (default 1gbit; the operator's link 20mbit, a good wireless link).
# down: SIGINT to each process started in a namespace (what Ctrl-C does: hr_graph stops its
# nodes in order), then SIGTERM to all inside after HR_HOSTS_STOP_S s (default 30), SIGKILL 5 s later.
set -euo pipefail

HOSTS=(robot compute operator)
declare -A ADDR=([robot]=10.231.0.1 [compute]=10.231.0.2 [operator]=10.231.0.3)
PREFIX=24

die() { echo "hosts.sh: $*" >&2; exit 1; }
P=${HR_HOSTS_PREFIX:-hr${SUDO_UID:-$(id -u)}}
[[ $P =~ ^[A-Za-z0-9]{1,8}$ ]] || die "HR_HOSTS_PREFIX must be 1-8 letters or digits, got '$P'"
BRIDGE=${P}_br
ns() { echo "${P}_$1"; }
port() { echo "${P}_${1:0:3}_br"; }  # the bridge's end of the host's link
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

ns_pids() {   # every process inside our namespaces (the graphs, their nodes, anything they spawned)
    local h; for h in "${HOSTS[@]}"; do ip netns pids "$(ns "$h")" 2>/dev/null || true; done
}

ns_roots() {   # the processes inside whose parent is outside (hr_graph, not the nodes it started)
    local all pid ppid; all=" $(ns_pids | tr '\n' ' ') "
    for pid in $all; do
        ppid=$(awk '/^PPid:/ {print $2}' "/proc/$pid/status" 2>/dev/null) || continue
        [[ $all == *" $ppid "* ]] || echo "$pid"
    done
}

stop_all() {   # stop_all SIGNAL DEADLINE_S [roots]: signal the processes inside; 0 once none is left
    local sig=$1 deadline=$2 pids
    if [[ ${3:-} == roots ]]; then pids=$(ns_roots); else pids=$(ns_pids); fi
    [[ -z $pids ]] && return 0
    # shellcheck disable=SC2086
    kill "-$sig" $pids 2>/dev/null || true
    local tries=$((deadline * 5))          # checks 0.2 s apart
    while [[ -n $(ns_pids) ]]; do
        (( tries-- > 0 )) || return 1
        sleep 0.2
    done
}

down() {
    need_root
    local n; n=$(ns_pids | wc -w)
    if (( n > 0 )); then
        local wait_s=${HR_HOSTS_STOP_S:-30}
        [[ $wait_s =~ ^[0-9]+$ ]] || die "HR_HOSTS_STOP_S must be whole seconds, got '$wait_s'"
        echo "hosts.sh: stopping $n process(es) in the namespaces (SIGINT, up to $wait_s s)"
        stop_all INT "$wait_s" roots || { echo "hosts.sh: still running after $wait_s s: SIGTERM" >&2
            stop_all TERM 5 || { echo "hosts.sh: still running: SIGKILL" >&2; stop_all KILL 5 || true; }; }
        local left; left=$(ns_pids | wc -w)
        (( left == 0 )) || die "$left process(es) still in the namespaces: $(ns_pids | tr '\n' ' ')"
    fi
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

names() {
    echo "bridge $BRIDGE"
    local h; for h in "${HOSTS[@]}"; do echo "$h $(ns "$h") $(port "$h") ${ADDR[$h]}"; done
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
    command -v "$1" >/dev/null || die "exec: '$1' not found on PATH (the package's executables: '. tools/env.sh' first)"
    ip netns exec "$(ns "$h")" env ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET "$@"
}

case ${1:-} in
    up) shift; up "$@" ;;
    down) down ;;
    status) status ;;
    names) names ;;
    cut) shift; cut "$@" ;;
    link) shift; link "$@" ;;
    exec) shift; run_on "$@" ;;
    *) die "usage: tools/hosts.sh up [--rate R] [--operator-rate R] [--delay MS] [--loss PCT] | down | status | names | cut HOST SECONDS | link HOST down|up | exec HOST CMD ..." ;;
esac
