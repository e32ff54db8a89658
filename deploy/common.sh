# Shared by install.sh and uninstall.sh (sourced, not run): exit codes, --root, the root check, dry runs.
# Expects $prog, $root and $dry to be set by the caller.

EX_USAGE=64 EX_NOPERM=77

# resolve_root: --root must exist; made absolute; "/" is the same as no --root.
resolve_root() {
    if [ -n "$root" ]; then
        [ -d "$root" ] || { echo "$prog: --root must be an existing directory, but got '$root'" >&2; exit $EX_USAGE; }
        root=$(cd "$root" && pwd)
        [ "$root" != / ] || root=""
    fi
    is_root=0
    if [ "$(id -u)" -eq 0 ]; then is_root=1; fi
}

# require_root VERB: changing / needs root; --dry-run and --root DIR do not.
require_root() {
    if [ $is_root -eq 0 ] && [ -z "$root" ] && [ $dry -eq 0 ]; then
        echo "$prog: must run as root to $1 (try sudo), or use --dry-run or --root DIR" >&2
        exit $EX_NOPERM
    fi
}

say() { printf '%s\n' "$*"; }
# act CMD...: run it, or print it on a dry run
act() { if [ $dry -eq 1 ]; then printf '+ %s\n' "$*"; else "$@"; fi; }
