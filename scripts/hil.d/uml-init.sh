#!/bin/bash
# init (process 1) of the user-mode Linux guest that scripts/hil boots:
#   linux.uml mem=1G root=/dev/root rootfstype=hostfs rootflags=/ rw init=<this> -- <out-dir>
# The guest's root filesystem is this machine's own (hostfs), so the project's virtual environment,
# the steps and the output directory are at the same absolute paths inside; whatever the guest
# writes lands on the host at once. Mounts proc and sys, runs guest.sh (which loads the CAN
# modules, creates the interface and runs the steps) and powers off. If even that fails, init
# exits: the kernel panics and linux.uml ends; the host reads the status file, not linux.uml's
# exit code.
OUT=${1:?usage: uml-init.sh <out-dir> (as init= on the linux.uml command line)}
export PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin
export HOME=/root
mount -t proc proc /proc
mount -t sysfs sysfs /sys
# Memory of the guest's own for files written while timing matters (a write to the host's
# filesystem holds the whole guest kernel until the host is done): a tmpfs, seen only inside.
export HIL_GUEST_TMP=$OUT/uml/mem
mkdir -p "$HIL_GUEST_TMP" && mount -t tmpfs -o size=512m,mode=700 tmpfs "$HIL_GUEST_TMP" \
    || unset HIL_GUEST_TMP
"$(dirname -- "$0")/guest.sh" "$OUT"
echo "uml-init: guest.sh exited $?, powering off"
sync
poweroff -f 2>/dev/null
# Without systemctl's poweroff: the magic SysRq key (the UML kernel has it).
echo o >/proc/sysrq-trigger
sleep 5
exit 1
