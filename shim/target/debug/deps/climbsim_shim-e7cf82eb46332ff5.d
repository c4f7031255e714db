/work/main/shim/target/debug/deps/climbsim_shim-e7cf82eb46332ff5.d: src/lib.rs src/abi/mod.rs src/abi/layout.rs src/abi/protocol.rs src/block.rs src/children.rs src/delivery.rs src/epoll.rs src/futex.rs src/give_way.rs src/handlers.rs src/held.rs src/io.rs src/ipc.rs src/maps.rs src/marker.rs src/native.rs src/net.rs src/now.rs src/park.rs src/port_ring.rs src/program.rs src/room.rs src/seccomp.rs src/signals/mod.rs src/signals/timers.rs src/signals/waits.rs src/slot.rs src/spawn.rs src/sync.rs src/sys.rs src/time.rs src/timerfd.rs src/tsc.rs src/turn.rs src/vdso.rs src/wait.rs

/work/main/shim/target/debug/deps/climbsim_shim-e7cf82eb46332ff5: src/lib.rs src/abi/mod.rs src/abi/layout.rs src/abi/protocol.rs src/block.rs src/children.rs src/delivery.rs src/epoll.rs src/futex.rs src/give_way.rs src/handlers.rs src/held.rs src/io.rs src/ipc.rs src/maps.rs src/marker.rs src/native.rs src/net.rs src/now.rs src/park.rs src/port_ring.rs src/program.rs src/room.rs src/seccomp.rs src/signals/mod.rs src/signals/timers.rs src/signals/waits.rs src/slot.rs src/spawn.rs src/sync.rs src/sys.rs src/time.rs src/timerfd.rs src/tsc.rs src/turn.rs src/vdso.rs src/wait.rs

src/lib.rs:
src/abi/mod.rs:
src/abi/layout.rs:
src/abi/protocol.rs:
src/block.rs:
src/children.rs:
src/delivery.rs:
src/epoll.rs:
src/futex.rs:
src/give_way.rs:
src/handlers.rs:
src/held.rs:
src/io.rs:
src/ipc.rs:
src/maps.rs:
src/marker.rs:
src/native.rs:
src/net.rs:
src/now.rs:
src/park.rs:
src/port_ring.rs:
src/program.rs:
src/room.rs:
src/seccomp.rs:
src/signals/mod.rs:
src/signals/timers.rs:
src/signals/waits.rs:
src/slot.rs:
src/spawn.rs:
src/sync.rs:
src/sys.rs:
src/time.rs:
src/timerfd.rs:
src/tsc.rs:
src/turn.rs:
src/vdso.rs:
src/wait.rs:

# env-dep:CARGO_MANIFEST_DIR=/work/main/shim
