# Sourced by the benchmark scripts: reads --max-spp, --seeds and --reference-spp (over the
# defaults the script set in max_spp, seeds and reference_spp), builds tessera's bench
# harness, and, where Python 3 is here, sets up Mitsuba 3 in target/bench-venv with Debian's
# libllvm19 for its llvm_ad_rgb variant (installed with apt-get when it can be). Sets `llvm`
# (empty without it) and `have_python` (1 or 0).
while [ $# -gt 0 ]; do
    case "$1" in
        --max-spp) max_spp="$2"; shift 2 ;;
        --seeds) seeds="$2"; shift 2 ;;
        --reference-spp) reference_spp="$2"; shift 2 ;;
        *) echo "unknown argument: $1" >&2; exit 2 ;;
    esac
done

cargo build --release -p tessera-cli --features bench
mkdir -p target/bench target/bench-cache
have_python=0
llvm=
if command -v python3 >/dev/null; then
    have_python=1
    if [ ! -x target/bench-venv/bin/python ]; then
        python3 -m venv target/bench-venv
        target/bench-venv/bin/pip install --quiet mitsuba numpy
    fi
    llvm=$(ls /usr/lib/*/libLLVM.so.19.1 2>/dev/null | head -1 || true)
    if [ -z "$llvm" ] && command -v apt-get >/dev/null && [ "$(id -u)" = 0 ]; then
        DEBIAN_FRONTEND=noninteractive apt-get install -y -q libllvm19 >/dev/null || true
        llvm=$(ls /usr/lib/*/libLLVM.so.19.1 2>/dev/null | head -1 || true)
    fi
    [ -n "$llvm" ] && export DRJIT_LIBLLVM_PATH="$llvm"
fi

# need_mitsuba WHO: ends the script that sourced this (WHO names it) unless Mitsuba's
# llvm_ad_rgb can run here.
need_mitsuba() {
    [ "$have_python" = 1 ] || { echo "$1 needs python3 for Mitsuba 3" >&2; exit 1; }
    [ -n "$llvm" ] || { echo "$1 needs Debian's libllvm19 for Mitsuba's llvm_ad_rgb" >&2; exit 1; }
}

# mitsuba_reference SCENE SPP FILE: Mitsuba's llvm_ad_rgb reference of SCENE at SPP, rendered
# into FILE unless FILE is already there (references are cached across runs; a run cut short
# leaves only FILE.tmp.exr behind, never a partial FILE).
mitsuba_reference() {
    [ -s "$3" ] && return 0
    target/bench-venv/bin/python bench/mitsuba_peer.py --variants llvm_ad_rgb \
        --make-reference "$1=$3.tmp.exr" --reference-spp "$2"
    mv "$3.tmp.exr" "$3"
}
