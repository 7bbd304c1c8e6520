# The ARM926EJ-S board's toolchain, sourced by `tools/arm926/board`.
#
# Debian's rustc-web (1.96) builds std from rust-web-src for
# armv5te-unknown-linux-gnueabi (no prebuilt std for that target exists
# here); Debian's gcc-arm-linux-gnueabi links, and qemu-user runs the
# result as the board's CPU (`-cpu arm926`: ARMv5TE, no FPU, no SIMD).
# The build has its own target folder, so it never invalidates the host
# build under target/release.

ARM_TARGET=armv5te-unknown-linux-gnueabi
ARM_SYSROOT=/usr/arm-linux-gnueabi
ARM_TARGET_DIR="${ARM_TARGET_DIR:-$PWD/target/arm926}"
ARM_QEMU=(qemu-arm -cpu arm926 -L "$ARM_SYSROOT")

# Debian's cargo, rustc and clippy first (rustup's shims would take over).
export PATH="/usr/bin:$PATH"
export RUSTC=/usr/bin/rustc RUSTDOC=/usr/bin/rustdoc
# -Zbuild-std is a nightly flag; Debian's stable rustc accepts it this way.
export RUSTC_BOOTSTRAP=1
export CARGO_TARGET_ARMV5TE_UNKNOWN_LINUX_GNUEABI_LINKER=arm-linux-gnueabi-gcc
export CARGO_TARGET_ARMV5TE_UNKNOWN_LINUX_GNUEABI_RUNNER="${ARM_QEMU[*]}"
export CC_armv5te_unknown_linux_gnueabi=arm-linux-gnueabi-gcc
export CARGO_TARGET_DIR="$ARM_TARGET_DIR"

# Cargo for the board: Debian's, with std built from source.
arm_cargo() {
    local sub=$1
    shift
    /usr/bin/cargo "$sub" -Zbuild-std=std,panic_abort --target "$ARM_TARGET" --release "$@"
}
