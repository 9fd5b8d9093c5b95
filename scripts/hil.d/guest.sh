#!/usr/bin/env bash
# Guest side of the HIL runner. Runs inside the virtual machine (user-mode Linux or QEMU) or
# directly on a host that already has the CAN interface: makes sure the CAN interface exists,
# then runs each step.
#
# Usage: guest.sh <out-dir>      Reads <out-dir>/config.env written by scripts/hil.
# Writes: <out-dir>/guest-started, <out-dir>/guest.log (this script's own log),
#         <out-dir>/steps/<name>/{log,rc,seconds,result.json}, <out-dir>/steps.tsv,
#         and last <out-dir>/status ("pass", "not judged: <steps>" or "fail <reason>").
# Exit status: 0 all steps passed, 1 a step failed, 2 setup failed, 3 no step failed but one or
# more were not judged (a step's exit 3: the machine could not carry what it measures, e.g. a
# starved VM under a real-time rehearsal; the step's log says why).
set -uo pipefail

OUT=${1:?usage: guest.sh <out-dir>}
# shellcheck source=/dev/null
set -a   # every HIL_ variable goes on to the steps
source "$OUT/config.env" || { echo "fail no config.env" >"$OUT/status"; exit 2; }
set +a
export PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin:$PATH
export HIL_OUT=$OUT HIL_D HIL_REPO HIL_PYTHON HIL_CAN_IF HIL_MODE
export PYTHONDONTWRITEBYTECODE=1   # read-only root under QEMU; elsewhere: leave the checkout as it is

now() { date +%s.%N; }
printf 'host_mode=%s\nuptime=%s\nkernel=%s\ncpus=%s\n' "$HIL_MODE" "$(cut -d' ' -f1 /proc/uptime)" \
    "$(uname -r)" "$(nproc)" >"$OUT/guest-started"
exec >>"$OUT/guest.log" 2>&1
echo "guest: kernel $(uname -r) ($(uname -m)), mode $HIL_MODE, uptime $(cut -d' ' -f1 /proc/uptime) s, $(nproc) cpus"

finish() { echo "$1" >"$OUT/status.tmp" && mv "$OUT/status.tmp" "$OUT/status"; sync; exit "$2"; }

# The user-mode Linux kernel keeps its modules in /usr/lib/uml/modules/<version>/, not in
# /lib/modules, so modprobe does not find them there: load them in dependency order by path
# (can-raw too: the kernel's own module autoload would look in /lib/modules as well).
load_uml_can_modules() {
    local dir m
    dir=/usr/lib/uml/modules/$(uname -r)/kernel
    [[ -d $dir ]] || { echo "guest: no module tree $dir"; return 1; }
    for m in drivers/net/can/dev/can-dev net/can/can net/can/can-raw drivers/net/can/vcan; do
        grep -q "^$(basename "$m" | tr - _) " /proc/modules && continue
        insmod "$dir/$m.ko" || return 1
    done
}

# Loopback: the simulator's control channel listens on 127.0.0.1 (a fresh guest has lo down).
ip link set up lo 2>/dev/null || true

# CAN interface
if ip link show "$HIL_CAN_IF" >/dev/null 2>&1; then
    echo "guest: $HIL_CAN_IF present"
else
    if [[ $HIL_MODE == uml ]]; then
        load_uml_can_modules || finish "fail setup: insmod of the CAN modules (can-dev, can, can-raw, vcan)" 2
    else
        modprobe vcan || finish "fail setup: modprobe vcan" 2
    fi
    ip link add dev "$HIL_CAN_IF" type vcan || finish "fail setup: ip link add $HIL_CAN_IF" 2
    echo "guest: created $HIL_CAN_IF"
fi
ip link set up "$HIL_CAN_IF" 2>/dev/null || ip link show "$HIL_CAN_IF" | grep -q '[<,]UP[,>]' \
    || finish "fail setup: $HIL_CAN_IF is down" 2
ip -details link show "$HIL_CAN_IF"
if [[ $HIL_MODE != direct ]]; then
    # The guest's own kernel: let sockets ask for large receive buffers (see smoke_can.py).
    sysctl -qw net.core.rmem_max=33554432 || true
fi

# Steps
mkdir -p "$OUT/steps"
: >"$OUT/steps.tsv"
failed=()
not_judged=()
# A step named in HIL_RETRY_STEPS (default: rehearsal) that fails or is not judged (exit 3; not
# a timeout) runs once more:
# on a shared host the guest's one CPU can be starved (hypervisor steal of 30-45 % was seen) until
# its 200 Hz stream collapses. The failed attempt stays in steps/<name>.attempt1, with its own
# line and log in the summary; the verdict is the second attempt's, except that a judged failure
# (exit 1) followed by "not judged" stays a failure.
HIL_RETRY_STEPS=${HIL_RETRY_STEPS-rehearsal}
queue=($HIL_STEPS)
declare -A first_rc=()   # a retried step: its first attempt's exit status
while ((${#queue[@]})); do
    step=${queue[0]}; queue=("${queue[@]:1}")
    exe=$HIL_D/steps/$step
    dir=$OUT/steps/$step
    mkdir -p "$dir"
    export HIL_STEP=$step HIL_STEP_OUT=$dir
    if [[ ! -x $exe ]]; then
        echo "guest: no executable step $exe" | tee "$dir/log"
        rc=127; secs=0
    else
        echo "guest: step $step start"
        t0=$(now)
        (cd "$dir" && timeout -k 10 "$HIL_STEP_TIMEOUT" "$exe" </dev/null >"$dir/log" 2>&1)
        rc=$?
        secs=$(awk -v a="$t0" -v b="$(now)" 'BEGIN{printf "%.3f", b-a}')
        ((rc == 124)) && echo "step timed out after $HIL_STEP_TIMEOUT s" >>"$dir/log"
        tail -n 5 "$dir/log"
    fi
    echo "$rc" >"$dir/rc"; echo "$secs" >"$dir/seconds"
    if ((rc != 0 && rc != 124)) && [[ " $HIL_RETRY_STEPS " == *" $step "* && -z ${first_rc[$step]-} ]]; then
        first_rc[$step]=$rc
        rm -rf -- "$dir.attempt1"; mv -- "$dir" "$dir.attempt1"
        printf '%s\t%s\t%s\n' "$step.attempt1" "$rc" "$secs" >>"$OUT/steps.tsv"
        echo "guest: step $step rc=$rc ${secs}s: failed; running it once more (HIL_RETRY_STEPS)"
        queue=("$step" "${queue[@]}")
        continue
    fi
    printf '%s\t%s\t%s\n' "$step" "$rc" "$secs" >>"$OUT/steps.tsv"
    echo "guest: step $step rc=$rc ${secs}s"
    if ((rc == 3 && ${first_rc[$step]-3} == 3)); then
        not_judged+=("$step")
    elif ((rc != 0)); then
        failed+=("$step")
    fi
done

if ((${#failed[@]})); then
    finish "fail steps: ${failed[*]}" 1
fi
if ((${#not_judged[@]})); then
    finish "not judged: ${not_judged[*]}" 3
fi
finish pass 0
