#!/usr/bin/env bash
# Runs one command inside a user-mode Linux kernel that has CAN, for machines
# whose own kernel has none (no vcan, socket(AF_CAN) fails).
#
# Debian's `user-mode-linux` kernel boots in about two seconds as an ordinary
# process and takes the host's filesystem as its root (hostfs), so the command
# runs our binaries as they are, in the current folder, with the current
# environment. Inside the guest, before the command:
#   - proc, sysfs, devpts (/dev/ptmx usable), tmpfs on /dev/shm and /tmp (so
#     the bus's shared memory and node files are the guest's own);
#   - the modules can, can-raw, can-dev, vcan and slcan loaded;
#   - vcan0 created and up (more with UML_CAN_VCANS="vcan0 vcan1").
# The command's stdout and stderr come back on this script's stdout and
# stderr once it has ended, and its exit status is this script's.
#
#   scripts/uml-can.sh candump -n 1 vcan0 & ...
#   scripts/uml-can.sh sh -c 'cansend vcan0 123#11 & candump -n 1 vcan0'
#   UML_CAN_TIMEOUT=60 scripts/uml-can.sh target/release/deps/can_kernel-... --exact test
#
# Installs user-mode-linux, kmod, iproute2 and can-utils with apt-get when
# missing. Exit status, besides the command's own:
#   77   skipped: user-mode-linux is not installed and cannot be (the reason
#        is printed on stderr);
#   124  the guest outlived UML_CAN_TIMEOUT seconds (default 120) and was killed;
#   125  the guest did not run the command (boot failure: its console log is
#        printed on stderr).
# Settings: UML_CAN_MEM (default 2G), UML_CAN_TIMEOUT, UML_CAN_VCANS,
# UML_CAN_WORK (the folder for the guest's files; default under target/).
# The guest mounts a tmpfs over /tmp; a checkout, work folder or current folder
# under /tmp is mounted back from the host over it (its top folder under /tmp).
set -uo pipefail

skip=77
guest_failed=125

if [ $# -eq 0 ]; then
    echo "usage: $0 COMMAND [ARGS...]" >&2
    exit 2
fi

root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)

# What the guest needs, installed when missing.
need=()
command -v linux >/dev/null 2>&1 || need+=(user-mode-linux)
command -v insmod >/dev/null 2>&1 || need+=(kmod)
command -v ip >/dev/null 2>&1 || need+=(iproute2)
command -v cansend >/dev/null 2>&1 || need+=(can-utils)
if [ ${#need[@]} -gt 0 ]; then
    echo "uml-can: installing ${need[*]}" >&2
    if [ "$(id -u)" -ne 0 ] || ! command -v apt-get >/dev/null 2>&1; then
        reason="not root or no apt-get"
    else
        export DEBIAN_FRONTEND=noninteractive
        apt_log=$(mktemp)
        if ! apt-get install -y --no-install-recommends "${need[@]}" >"$apt_log" 2>&1; then
            # A stale package list gives 404s: refresh it once and try again.
            apt-get update >>"$apt_log" 2>&1
            apt-get install -y --no-install-recommends "${need[@]}" >>"$apt_log" 2>&1
        fi
        reason="apt-get install ${need[*]} failed: $(tail -n 3 "$apt_log" | tr '\n' ' ')"
        rm -f "$apt_log"
    fi
    if ! command -v linux >/dev/null 2>&1; then
        echo "uml-can: SKIPPED: user-mode-linux cannot be installed ($reason)" >&2
        exit $skip
    fi
    for tool in insmod ip cansend; do
        if ! command -v $tool >/dev/null 2>&1; then
            echo "uml-can: $tool is missing and could not be installed ($reason)" >&2
            exit $guest_failed
        fi
    done
fi

modules=$(ls -d /usr/lib/uml/modules/*/ 2>/dev/null | head -n 1)
if [ -z "$modules" ]; then
    echo "uml-can: user-mode-linux has no modules under /usr/lib/uml/modules" >&2
    exit $guest_failed
fi

work_parent=${UML_CAN_WORK:-$root/target/uml-can}
mkdir -p "$work_parent"
work=$(mktemp -d "$work_parent/run.XXXXXX")
trap 'rm -rf "$work"' EXIT

# The host folders under /tmp the guest needs (its own /tmp is a tmpfs): the top
# folder under /tmp of each, once.
tmp_keep=()
for path in "$work" "$PWD" "$root"; do
    case "$path" in
    /tmp/?*)
        top=/tmp/$(cut -d/ -f3 <<<"$path")
        case " ${tmp_keep[*]-} " in *" $top "*) ;; *) tmp_keep+=("$top") ;; esac
        ;;
    esac
done

# The guest's init: a bash script on the host's filesystem, with this shell's
# environment, folder and command written into it.
{
    echo '#!/bin/bash'
    export -p
    echo "export PATH=\"\$PATH:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin\""
    printf 'work=%q\n' "$work"
    printf 'modules=%q\n' "$modules"
    printf 'vcans=%q\n' "${UML_CAN_VCANS:-vcan0}"
    printf 'cwd=%q\n' "$PWD"
    printf 'tmp_keep=('
    [ ${#tmp_keep[@]} -eq 0 ] || printf '%q ' "${tmp_keep[@]}"
    printf ')\n'
    printf 'command=('
    printf '%q ' "$@"
    printf ')\n'
    cat <<'EOF'
setup() {
    mount -t proc proc /proc &&
        mount -t sysfs sysfs /sys &&
        mkdir -p /dev/shm &&
        mount -t tmpfs -o mode=1777 tmpfs /dev/shm &&
        mount -t tmpfs -o mode=1777 tmpfs /tmp || return 1
    for keep in "${tmp_keep[@]}"; do
        mkdir -p "$keep" && mount -t hostfs none "$keep" -o "$keep" || return 1
    done
    mkdir -p /dev/pts &&
        mount -t devpts -o newinstance,ptmxmode=0666 devpts /dev/pts &&
        ln -sf /dev/pts/ptmx /dev/ptmx || return 1
    for m in net/can/can.ko net/can/can-raw.ko drivers/net/can/dev/can-dev.ko \
        drivers/net/can/vcan.ko drivers/net/can/slcan/slcan.ko; do
        insmod "$modules/kernel/$m" || return 1
    done
    ip link set lo up || return 1
    for v in $vcans; do
        ip link add dev "$v" type vcan && ip link set up "$v" || return 1
    done
}
if setup >"$work/setup.log" 2>&1; then
    cd "$cwd" && "${command[@]}" >"$work/stdout" 2>"$work/stderr" </dev/null
    echo $? >"$work/rc.part"
    mv "$work/rc.part" "$work/rc"
else
    echo "guest setup failed" >>"$work/setup.log"
fi
sync
echo o >/proc/sysrq-trigger 2>/dev/null
poweroff -f
EOF
} >"$work/init"
chmod +x "$work/init"

# The kernel in its own process group, so a timeout kills all its threads.
timeout_s=${UML_CAN_TIMEOUT:-120}
setsid linux "mem=${UML_CAN_MEM:-2G}" "umid=jetbench-can-$$-$RANDOM" root=/dev/root rootfstype=hostfs \
    rootflags=/ rw quiet "init=$work/init" con=null con0=null,fd:3 \
    3>"$work/console" </dev/null >/dev/null 2>>"$work/console" &
guest=$!
timed_out=0
for ((tick = 0; ; tick++)); do
    kill -0 $guest 2>/dev/null || break
    if ((tick >= timeout_s * 10)); then
        timed_out=1
        kill -KILL -- -$guest 2>/dev/null
        break
    fi
    sleep 0.1
done
wait $guest 2>/dev/null

[ -f "$work/stdout" ] && cat "$work/stdout"
[ -f "$work/stderr" ] && cat "$work/stderr" >&2
if ((timed_out)); then
    echo "uml-can: the guest ran longer than ${timeout_s} s and was killed" >&2
    exit 124
fi
if [ ! -f "$work/rc" ]; then
    echo "uml-can: the guest did not run the command; its setup and console:" >&2
    cat "$work/setup.log" "$work/console" >&2 2>/dev/null
    exit $guest_failed
fi
exit "$(cat "$work/rc")"
