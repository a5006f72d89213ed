#!/usr/bin/env bash
# Runs the vcan integration tests (tests/vcan, marker `vcan`) on real SocketCAN.
#
#   scripts/vcan-tests.sh [ARGS]            host: native when vcan0 and vcan1 exist, else a VM
#   scripts/vcan-tests.sh --guest D [ARGS]  inside the VM: create vcan0/vcan1, run pytest in D
#
# ARGS go to pytest (e.g. `-k publisher` while working on one test file).
#
# The VM is virtme-ng (PyPI) on qemu-system-x86 without KVM, booting a Debian kernel
# (linux-image-amd64) over the host's root file system, read-only. Only the results directory
# is writable from the guest. The run FAILS when a test failed, errored or was skipped, or
# when nothing was collected: a broken VM path cannot pass silently. See docs/vcan.md.
set -euo pipefail

cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}
PY=$VENV/bin/python
VCAN_IFACES=(vcan0 vcan1)
VM_MEMORY=${ATRIS_VCAN_VM_MEMORY:-2G}
VM_TIMEOUT_S=${ATRIS_VCAN_VM_TIMEOUT_S:-1500}
APT_PKGS=(qemu-system-x86 linux-image-amd64 busybox-static can-utils)

log() { echo "vcan-tests: $*"; }
die() { echo "vcan-tests: error: $*" >&2; exit 1; }

# pytest over tests/vcan only, no cache or bytecode writes (the repo is read-only in the VM)
run_pytest() {
  local results=$1
  shift
  PYTHONDONTWRITEBYTECODE=1 HYPOTHESIS_STORAGE_DIRECTORY="$results/.hypothesis" \
    ATRIS_VCAN_RESULTS="$results" \
    "$PY" -m pytest -m vcan tests/vcan -p no:cacheprovider -q -rA \
    -o junit_family=xunit1 --junitxml="$results/junit.xml" "$@"
}

have_vcan() {
  local iface
  for iface in "${VCAN_IFACES[@]}"; do
    ip link show "$iface" >/dev/null 2>&1 || return 1
  done
}

# --- inside the VM ----------------------------------------------------------------------
guest_main() {
  local results=$1 iface rc=0
  shift
  modprobe vcan
  for iface in "${VCAN_IFACES[@]}"; do
    ip link add dev "$iface" type vcan
    ip link set "$iface" up
  done
  log "guest kernel $(uname -r), $(nproc) CPU(s), booted in $(cut -d' ' -f1 /proc/uptime) s"
  export NUMBA_CACHE_DIR="$results/numba" NUMBA_CPU_NAME=generic  # see compile_for_vm
  run_pytest "$results" "$@" || rc=$?
  return "$rc"
}

# --- host: what the VM needs --------------------------------------------------------------
guest_kernel() {
  local k ver
  for k in $(ls -1 /boot/vmlinuz-* 2>/dev/null | sort -rV); do
    ver=${k#/boot/vmlinuz-}
    if find "/lib/modules/$ver" -name 'vcan.ko*' 2>/dev/null | grep -q .; then
      echo "$k"; return 0
    fi
  done
  return 1
}

missing_apt_pkgs() {
  command -v qemu-system-x86_64 >/dev/null || echo qemu-system-x86
  guest_kernel >/dev/null || echo linux-image-amd64
  [ -x /bin/busybox ] || [ -x /usr/bin/busybox ] || echo busybox-static
  command -v cangen >/dev/null || echo can-utils
}

ensure_vm_tools() {
  local missing
  missing=$(missing_apt_pkgs | xargs)
  if [ -n "$missing" ]; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
      log "installing $missing"
      export DEBIAN_FRONTEND=noninteractive
      apt-get update -qq
      # shellcheck disable=SC2086
      apt-get install -y -qq --no-install-recommends $missing >/dev/null
    else
      die "no vcan0/vcan1 on this host and the test VM needs: $missing
  install them with: sudo apt-get install ${APT_PKGS[*]}
  or run natively: sudo modprobe vcan; for i in ${VCAN_IFACES[*]}; do
    sudo ip link add dev \$i type vcan; sudo ip link set \$i up; done"
    fi
  fi
  [ -x "$VENV/bin/vng" ] || { log "installing virtme-ng into $VENV"; "$PY" -m pip install -q virtme-ng; }
}

# The numba kernels, compiled here for a generic x86-64 CPU into the results directory:
# the repo is read-only in the VM (no cache in __pycache__) and the emulated CPU is not the
# host's (a host-CPU cache would not match), so the VM would otherwise compile them again,
# minutes without KVM. One simulated block goes through the pipeline (`roles.py warm`):
# kernels compiled at their first call are cached too, and the units' zygote in the VM only
# loads them (it compiled them for itself for over 300 s, the first test's whole timeout).
compile_for_vm() {
  local results=$1 start=$SECONDS
  NUMBA_CACHE_DIR="$results/numba" NUMBA_CPU_NAME=generic "$PY" tests/vcan/roles.py warm \
    || die "the pipeline's kernels do not compile"
  log "kernels compiled for the VM in $((SECONDS - start)) s"
}

run_in_vm() {
  local results=$1 kernel
  shift
  ensure_vm_tools
  compile_for_vm "$results"
  kernel=$(guest_kernel) || die "no kernel in /boot with a vcan module"
  log "booting $kernel without KVM (${VM_MEMORY}, 2 CPUs), results in $results"
  PATH="$PWD/$VENV/bin:$PATH" timeout "$VM_TIMEOUT_S" vng --run "$kernel" --disable-kvm \
    --memory "$VM_MEMORY" --cpus 2 --rwdir "$results" \
    --exec "bash scripts/vcan-tests.sh --guest $results ${*@Q}" </dev/null 2>&1 | cat
  # (stdout and stderr through a pipe: qemu re-opens them by path, which would overwrite a
  # log file that `make test > log 2>&1` writes: the host tier's output was lost)
}

# --- host: the verdict ----------------------------------------------------------------------
host_main() {
  local results rc=0 start=$SECONDS
  results=$(mktemp -d "${TMPDIR:-/tmp}/atris-vcan.XXXXXX")
  if have_vcan; then
    log "host has ${VCAN_IFACES[*]}: running natively"
    run_pytest "$results" "$@" || rc=$?
  else
    log "host has no ${VCAN_IFACES[*]}: running in a virtme-ng VM"
    run_in_vm "$results" "$@" || rc=$?
  fi
  log "finished in $((SECONDS - start)) s (exit code $rc)"
  "$PY" scripts/check_junit.py "$results/junit.xml" || rc=1
  if [ "$rc" != 0 ] && [ -s "$results/units.log" ]; then
    log "stderr of the unit processes (last 60 lines):"
    tail -n 60 "$results/units.log"
  fi
  rm -rf "$results"
  return "$rc"
}

if [ "${1:-}" = "--guest" ]; then
  [ $# -ge 2 ] || die "usage: $0 --guest RESULTS_DIR [PYTEST_ARGS]"
  shift
  guest_main "$@"
else
  host_main "$@"
fi
