#!/usr/bin/env bash
# Install uav-depth as a systemd service on a companion computer, in one step.
#
# Lays down (paths relative to --root, default /):
#   /etc/sysusers.d/uav-depth.conf      system user uav-depth (groups video, dialout), via systemd-sysusers
#   /opt/uav-depth/venv/                Python virtual environment with uav-depth (root-owned, read-only to the service)
#   /opt/uav-depth/share/               README.md, the unit, example configs
#   /etc/uav-depth/config.yaml          from an example, root:uav-depth 0640; an existing one is never overwritten
#   /var/lib/uav-depth/{params.yaml,logs/}  state, uav-depth:uav-depth 0750; params.yaml (deploy/params-flight.yaml,
#                                       checked by the installed package) only if absent
#   /etc/udev/rules.d/80-uav-depth-oak.rules  OAK-D USB access for group video
#   /etc/systemd/system/uav-depth.service     enabled (multi-user.target), not started
# Idempotent: a second run upgrades the package and changes nothing else.
set -euo pipefail
umask 022

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
src_default=$(dirname "$here")
prog=install.sh
. "$(dirname "${BASH_SOURCE[0]}")/common.sh"

usage() {
    cat <<EOF
usage: $prog [--root DIR] [--dry-run] [--camera NAME] [--from SPEC] [--python PY] [--no-deps] [--no-enable]

  --root DIR     install into DIR instead of / (an image being built, or a test): the user is
                 created with systemd-sysusers --root, the unit enabled with systemctl --root;
                 nothing is started or reloaded. Allowed without root (ownership then left as is).
  --dry-run      print every action, change nothing (allowed without root)
  --camera NAME  example that becomes /etc/uav-depth/config.yaml if there is none:
                 zed-mini (ZED Mini over UVC, default), oak-d (adds the [oak] extra), sitl
  --from SPEC    what pip installs (default: this checkout, $src_default)
  --python PY    interpreter for the virtual environment (default: python3)
  --no-deps      pass --no-deps to pip (offline images and tests; dependencies provided otherwise)
  --no-enable    install the unit but do not enable it
EOF
}

root="" dry=0 camera=zed-mini from="" python=python3 nodeps=0 enable=1
while [ $# -gt 0 ]; do
    case "$1" in
        --root) [ $# -ge 2 ] || { echo "$prog: --root needs a directory" >&2; exit $EX_USAGE; }; root=$2; shift 2 ;;
        --root=*) root=${1#*=}; shift ;;
        --dry-run) dry=1; shift ;;
        --camera) [ $# -ge 2 ] || { echo "$prog: --camera needs a name" >&2; exit $EX_USAGE; }; camera=$2; shift 2 ;;
        --camera=*) camera=${1#*=}; shift ;;
        --from) [ $# -ge 2 ] || { echo "$prog: --from needs a pip requirement" >&2; exit $EX_USAGE; }; from=$2; shift 2 ;;
        --from=*) from=${1#*=}; shift ;;
        --python) [ $# -ge 2 ] || { echo "$prog: --python needs an interpreter" >&2; exit $EX_USAGE; }; python=$2; shift 2 ;;
        --python=*) python=${1#*=}; shift ;;
        --no-deps) nodeps=1; shift ;;
        --no-enable) enable=0; shift ;;
        -h|--help) usage; exit 0 ;;
        *) echo "$prog: unknown argument '$1' (see --help)" >&2; exit $EX_USAGE ;;
    esac
done

case "$camera" in
    zed-mini|oak-d|sitl) ;;
    *) echo "$prog: --camera must be one of zed-mini, oak-d, sitl, but got '$camera'" >&2; exit $EX_USAGE ;;
esac
resolve_root
require_root "install into /"
if [ -z "$from" ]; then
    from=$src_default
    if [ "$camera" = oak-d ]; then from="$src_default[oak]"; fi
fi

venv=/opt/uav-depth/venv
# Run a command, or only print it under --dry-run.

# Ownership: names on /, numeric ids read from the root's own databases under --root (the
# host's uav-depth, if any, is not the image's). Without root privileges ownership is left alone.
idof() {  # idof passwd|group NAME -> numeric id, or NAME when not (yet) there
    local id
    id=$(awk -F: -v n="$2" '$1 == n { print $3; exit }' "$root/etc/$1" 2>/dev/null || true)
    printf '%s' "${id:-$2}"
}
own() {  # own USER GROUP PATH...
    local u=$1 g=$2; shift 2
    if [ $is_root -eq 0 ] && [ $dry -eq 0 ]; then return 0; fi
    if [ -n "$root" ]; then u=$(idof passwd "$u"); g=$(idof group "$g"); fi
    act chown "$u:$g" "$@"
}
put() {  # put MODE SRC DST: install a file we own (always replaced: it is ours, not the admin's)
    act install -m "$1" "$2" "$root$3"
    own root root "$root$3"
}

say "uav-depth install into ${root:-/}$([ $dry -eq 1 ] && echo ' (dry run: nothing is changed)')"

# 0. Preconditions, checked before anything changes.
command -v "$python" >/dev/null || { echo "$prog: Python interpreter '$python' not found (--python)" >&2; exit 1; }
"$python" -c 'import venv, ensurepip' 2>/dev/null || {
    echo "$prog: $python cannot create virtual environments: install python3-venv (apt-get install python3-venv)" >&2
    exit 1; }
for f in uav-depth.service uav-depth.sysusers 80-uav-depth-oak.rules "examples/$camera.yaml"; do
    [ -f "$here/$f" ] || { echo "$prog: missing $here/$f (run from a complete checkout)" >&2; exit 1; }
done

# 1. The system user: systemd-sysusers is declarative, idempotent and takes --root.
act install -d -m 0755 "$root/etc/sysusers.d"
put 0644 "$here/uav-depth.sysusers" /etc/sysusers.d/uav-depth.conf
if command -v systemd-sysusers >/dev/null; then
    if [ -n "$root" ]; then
        act systemd-sysusers --root="$root" "$root/etc/sysusers.d/uav-depth.conf"
    else
        act systemd-sysusers /etc/sysusers.d/uav-depth.conf
    fi
elif [ -z "$root" ]; then  # no systemd-sysusers (unusual on a systemd host): the same with shadow-utils
    getent passwd uav-depth >/dev/null || act useradd --system --user-group --home-dir /var/lib/uav-depth \
        --no-create-home --shell /usr/sbin/nologin --comment "uav-depth stereo ranging daemon" uav-depth
    act usermod -a -G video,dialout uav-depth
else
    echo "$prog: --root needs systemd-sysusers (Debian package systemd) to create the user" >&2; exit 1
fi

# 2. The virtual environment: root-owned, the service only reads it.
act install -d -m 0755 "$root/opt/uav-depth" "$root/opt/uav-depth/share" "$root/opt/uav-depth/share/examples"
if [ -x "$root$venv/bin/python" ]; then
    say "keeping virtual environment $root$venv (upgrading uav-depth in it)"
else
    act "$python" -m venv "$root$venv"
fi
pip_args=(install --quiet --disable-pip-version-check --upgrade)
if [ $nodeps -eq 1 ]; then pip_args+=(--no-deps); fi
act "$root$venv/bin/python" -m pip "${pip_args[@]}" "$from"
if [ -n "$root" ]; then
    # pip wrote $root$venv into script shebangs and activate scripts; on the target the venv is at $venv.
    if [ $dry -eq 1 ]; then
        say "+ rewrite $root$venv to $venv in $root$venv/bin/* and pyvenv.cfg"
    else
        { find "$root$venv/bin" -maxdepth 1 -type f -print0 | xargs -0 -r grep -lIF "$root$venv" || true; } \
            | while IFS= read -r f; do sed -i "s|$root$venv|$venv|g" "$f"; done
        sed -i "s|$root$venv|$venv|g" "$root$venv/pyvenv.cfg"
    fi
fi
put 0644 "$src_default/README.md" /opt/uav-depth/share/README.md
put 0644 "$here/uav-depth.service" /opt/uav-depth/share/uav-depth.service
for ex in "$here"/examples/*.yaml; do
    put 0644 "$ex" "/opt/uav-depth/share/examples/$(basename "$ex")"
done

# 3. Configuration: readable by the service, writable by root only. Never overwritten.
act install -d -m 0750 "$root/etc/uav-depth"
own root uav-depth "$root/etc/uav-depth"
if [ -e "$root/etc/uav-depth/config.yaml" ]; then
    say "keeping existing $root/etc/uav-depth/config.yaml"
else
    act install -m 0640 "$here/examples/$camera.yaml" "$root/etc/uav-depth/config.yaml"
    own root uav-depth "$root/etc/uav-depth/config.yaml"
fi

# 4. State: the parameter file the daemon hot-reloads (and the tuner's results replace) and frame logs.
act install -d -m 0750 "$root/var/lib/uav-depth" "$root/var/lib/uav-depth/logs"
own uav-depth uav-depth "$root/var/lib/uav-depth" "$root/var/lib/uav-depth/logs"
params="$root/var/lib/uav-depth/params.yaml"
params_bad=0
if [ -e "$params" ] && [ $dry -eq 1 ]; then
    say "keeping existing $params (after uav-depth params check)"
elif [ -e "$params" ]; then
    # An operator's (or the tuner's) file is never replaced, but an invalid one is not kept silently:
    # the daemon would refuse it at start (exit 78) and fly nothing.
    why=$("$root$venv/bin/python" -m uav_depth.cli.main params check "$params" 2>&1) && rc=0 || rc=$?
    if [ $rc -eq 0 ]; then
        say "keeping existing $params (${why##*$'\n'})"
    elif [ $rc -eq 78 ]; then
        params_bad=1
        say "existing $params is INVALID and was kept as it is: ${why##*$'\n'}"
        say "the daemon refuses it at start (exit 78); fix it, or remove it and run install.sh again for the flight file"
    else
        say "keeping existing $params; the installed package could not check it (${why##*$'\n'})"
    fi
elif [ $dry -eq 1 ]; then
    say "+ install -m 0640 $here/params-flight.yaml $params (after uav-depth params check)"
elif why=$("$root$venv/bin/python" -m uav_depth.cli.main params check "$here/params-flight.yaml" 2>&1); then
    # The flight file, not the manual baseline: the baseline takes about 0.6 s per 1280x720
    # frame on a 2-core computer, older than any estimate the daemon may send as valid.
    # It is checked by the installed schema itself before it becomes the daemon's file.
    install -m 0640 "$here/params-flight.yaml" "$params.tmp" && mv "$params.tmp" "$params"
    own uav-depth uav-depth "$params"
else
    rm -f "$params.tmp"
    say "not writing $params: the installed package does not accept it (${why##*$'\n'}); the daemon uses its built-in defaults"
fi

# 5. Devices: OAK-D over USB for group video.
act install -d -m 0755 "$root/etc/udev/rules.d"
put 0644 "$here/80-uav-depth-oak.rules" /etc/udev/rules.d/80-uav-depth-oak.rules
if [ -z "$root" ] && [ -d /run/udev ] && command -v udevadm >/dev/null; then
    act udevadm control --reload-rules
    act udevadm trigger --subsystem-match=usb --attr-match=idVendor=03e7
fi

# 6. The unit.
act install -d -m 0755 "$root/etc/systemd/system"
put 0644 "$here/uav-depth.service" /etc/systemd/system/uav-depth.service
booted=0
if [ -z "$root" ] && [ -d /run/systemd/system ]; then booted=1; fi
if [ $booted -eq 1 ]; then act systemctl daemon-reload; fi
if [ $enable -eq 1 ]; then
    if [ -n "$root" ]; then act systemctl --root="$root" enable uav-depth.service
    else act systemctl enable uav-depth.service; fi
fi
# An upgrade takes effect at once if the service was running; a first install is not started.
if [ $booted -eq 1 ]; then act systemctl try-restart uav-depth.service; fi

# 7. Check the config with the installed package: a bad one would only show in the journal later.
cfg_check=(-m uav_depth.cli.main run --check --config "$root/etc/uav-depth/config.yaml")
if [ $dry -eq 1 ]; then
    say "+ $root$venv/bin/python ${cfg_check[*]}"
elif out=$("$root$venv/bin/python" "${cfg_check[@]}" 2>&1); then
    say "$out"
else
    say "config check failed, the service will not start until this is fixed: ${out##*$'\n'}"
fi

if [ $params_bad -eq 1 ]; then
    echo "$prog: installed, but the kept parameter file $params is invalid (see above)" >&2
    exit 1
fi
say "done. Edit ${root}/etc/uav-depth/config.yaml, then: systemctl start uav-depth; journalctl -u uav-depth -f"
