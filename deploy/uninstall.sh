#!/usr/bin/env bash
# Remove what deploy/install.sh installed. The configuration (/etc/uav-depth), the state
# (/var/lib/uav-depth: tuned parameters, frame logs) and the uav-depth user are kept unless
# --purge is given: they are the operator's work, not ours.
set -euo pipefail

prog=uninstall.sh
. "$(dirname "${BASH_SOURCE[0]}")/common.sh"

usage() {
    cat <<EOF
usage: $prog [--root DIR] [--dry-run] [--purge]

  --root DIR  remove from DIR instead of / (an image, or a test); nothing is stopped or reloaded
  --dry-run   print every action, change nothing (allowed without root)
  --purge     also remove /etc/uav-depth, /var/lib/uav-depth (tuned parameters, logs) and the user
EOF
}

root="" dry=0 purge=0
while [ $# -gt 0 ]; do
    case "$1" in
        --root) [ $# -ge 2 ] || { echo "$prog: --root needs a directory" >&2; exit $EX_USAGE; }; root=$2; shift 2 ;;
        --root=*) root=${1#*=}; shift ;;
        --dry-run) dry=1; shift ;;
        --purge) purge=1; shift ;;
        -h|--help) usage; exit 0 ;;
        *) echo "$prog: unknown argument '$1' (see --help)" >&2; exit $EX_USAGE ;;
    esac
done
resolve_root
require_root "remove from /"

remove() {  # remove PATH...: only what exists, so a second run is a no-op
    local p
    for p in "$@"; do
        if [ -e "$p" ] || [ -L "$p" ]; then act rm -rf -- "$p"; fi
    done
}

say "uav-depth uninstall from ${root:-/}$([ $dry -eq 1 ] && echo ' (dry run: nothing is changed)')"
booted=0
if [ -z "$root" ] && [ -d /run/systemd/system ]; then booted=1; fi
unit="$root/etc/systemd/system/uav-depth.service"
if [ -e "$unit" ]; then
    if [ -n "$root" ]; then act systemctl --root="$root" disable uav-depth.service
    elif [ $booted -eq 1 ]; then act systemctl disable --now uav-depth.service
    else act systemctl disable uav-depth.service; fi
fi
remove "$unit" "$root/etc/systemd/system/multi-user.target.wants/uav-depth.service"
if [ $booted -eq 1 ]; then act systemctl daemon-reload; fi
remove "$root/opt/uav-depth" "$root/etc/udev/rules.d/80-uav-depth-oak.rules"
if [ -z "$root" ] && [ -d /run/udev ] && command -v udevadm >/dev/null; then act udevadm control --reload-rules; fi

if [ $purge -eq 1 ]; then
    remove "$root/etc/uav-depth" "$root/var/lib/uav-depth" "$root/etc/sysusers.d/uav-depth.conf"
    if grep -q '^uav-depth:' "$root/etc/passwd" 2>/dev/null; then
        if [ -n "$root" ]; then
            if [ $is_root -eq 1 ]; then act userdel --root "$root" uav-depth
            else say "not root: leaving user uav-depth in $root/etc/passwd"; fi
        else
            act userdel uav-depth
        fi
    fi
    if grep -q '^uav-depth:' "$root/etc/group" 2>/dev/null; then
        if [ -n "$root" ]; then
            if [ $is_root -eq 1 ]; then act groupdel --root "$root" uav-depth; fi
        else
            act groupdel uav-depth
        fi
    fi
else
    for kept in /etc/uav-depth /var/lib/uav-depth; do
        if [ -e "$root$kept" ]; then say "keeping $root$kept (remove with --purge)"; fi
    done
    if [ -e "$root/etc/sysusers.d/uav-depth.conf" ]; then
        say "keeping user uav-depth and $root/etc/sysusers.d/uav-depth.conf (remove with --purge)"
    fi
fi
say "done."
