#!/usr/bin/env bash
# Installs what the HIL runner needs on the host, for one mode:
#   uml:    Debian's user-mode Linux kernel (linux.uml, with CAN, CAN_RAW and VCAN modules under
#           /usr/lib/uml/modules/<version>/), kmod (insmod), can-utils, iproute2.
#   qemu:   apt packages (kernel image, QEMU, kmod, can-utils, iproute2, a static busybox for
#           virtme-ng's initramfs) and virtme-ng in a virtual environment of its own.
#   direct: can-utils and iproute2 only (the host already has the CAN interface).
# Usage: install.sh uml|qemu|direct <hil-venv-dir>     Quiet when everything is present already.
# Exit status: 0 ready; 2 cannot install (reason on the last line of stderr).
set -euo pipefail

USAGE="usage: install.sh uml|qemu|direct <hil-venv-dir>"
MODE=${1:?$USAGE}
HIL_VENV=${2:?$USAGE}
case $MODE in
    uml) APT_PKGS=(user-mode-linux kmod can-utils iproute2) ;;
    qemu) APT_PKGS=(linux-image-amd64 qemu-system-x86 kmod can-utils iproute2 busybox-static file) ;;
    direct) APT_PKGS=(can-utils iproute2) ;;
    *) echo "$USAGE" >&2; exit 2 ;;
esac

die() { echo "hil install: $*" >&2; exit 2; }
log() { echo "hil install: $*" >&2; }

have_kernel() { compgen -G '/boot/vmlinuz-*' >/dev/null; }

static_busybox() {
    # virtme-ng needs a statically linked busybox for its initramfs, and checks that with `file`.
    local b
    command -v file >/dev/null || return 1
    b=$(command -v busybox-static || command -v busybox.static || command -v busybox) || return 1
    file -L "$b" | grep -Eq 'statically linked|static-pie linked'
}

# The UML kernel's own module tree, with the CAN modules the guest loads.
uml_modules() {
    local v
    command -v linux.uml >/dev/null || return 1
    v=$(linux.uml --version 2>/dev/null) || return 1
    local m=/usr/lib/uml/modules/$v/kernel
    [[ -r $m/drivers/net/can/vcan.ko && -r $m/net/can/can-raw.ko ]]
}

missing=()
command -v candump >/dev/null || missing+=(can-utils)
command -v ip >/dev/null || missing+=(iproute2)
case $MODE in
    uml)
        command -v insmod >/dev/null || missing+=(kmod)
        uml_modules || missing+=(user-mode-linux)
        ;;
    qemu)
        command -v qemu-system-x86_64 >/dev/null || missing+=(qemu-system-x86)
        command -v modprobe >/dev/null || missing+=(kmod)
        have_kernel || missing+=(linux-image-amd64)
        static_busybox || missing+=(busybox-static file)
        ;;
esac

if ((${#missing[@]})); then
    command -v apt-get >/dev/null || die "missing ${missing[*]} and there is no apt-get on this machine; install them by hand"
    [[ $(id -u) == 0 ]] || die "missing ${missing[*]}; installing them needs root (run as root or install them by hand)"
    export DEBIAN_FRONTEND=noninteractive
    apt_opts=(-y -q --no-install-recommends -o DPkg::Lock::Timeout=600)
    log "apt-get install ${APT_PKGS[*]} (missing: ${missing[*]})"
    if ! apt-get update -q -o DPkg::Lock::Timeout=600 >&2; then
        log "apt-get update failed; trying the package lists already present"
    fi
    apt-get install "${apt_opts[@]}" "${APT_PKGS[@]}" >&2 \
        || die "apt-get install ${APT_PKGS[*]} failed"
fi

for c in candump ip; do
    command -v "$c" >/dev/null || die "$c still not found after installing"
done
case $MODE in
    direct) exit 0 ;;
    uml)
        command -v insmod >/dev/null || die "insmod still not found after installing kmod"
        uml_modules || die "no linux.uml with CAN modules under /usr/lib/uml/modules/<version>/ after installing user-mode-linux"
        exit 0
        ;;
esac

have_kernel || die "no /boot/vmlinuz-* after installing linux-image-amd64"
for c in qemu-system-x86_64 modprobe; do
    command -v "$c" >/dev/null || die "$c still not found after installing"
done
static_busybox || die "no statically linked busybox after installing busybox-static"
# The guest loads vcan from the host's module tree of the same kernel version.
for k in /boot/vmlinuz-*; do
    v=${k#/boot/vmlinuz-}
    [[ -d /lib/modules/$v ]] || die "$k has no module tree /lib/modules/$v"
done

if [[ ! -x $HIL_VENV/bin/vng ]]; then
    py=$(command -v python3) || die "no python3 on PATH"
    log "creating $HIL_VENV with virtme-ng"
    "$py" -m venv "$HIL_VENV" || die "python3 -m venv $HIL_VENV failed (on Debian/Ubuntu: apt-get install python3-venv)"
    "$HIL_VENV/bin/pip" install -q virtme-ng >&2 || die "pip install virtme-ng failed"
    [[ -x $HIL_VENV/bin/vng ]] || die "virtme-ng installed but $HIL_VENV/bin/vng is missing"
fi
