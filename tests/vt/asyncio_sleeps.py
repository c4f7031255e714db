#!/usr/bin/env python3
"""asyncio (which waits in epoll) on simulated time: sleeps, concurrent sleeps, a timeout."""
import asyncio
import time


async def main():
    t0 = time.monotonic()
    await asyncio.sleep(0.5)
    first = time.monotonic() - t0
    await asyncio.gather(asyncio.sleep(0.2), asyncio.sleep(0.3))
    second = time.monotonic() - t0
    try:
        await asyncio.wait_for(asyncio.sleep(10), timeout=0.25)
    except asyncio.TimeoutError:
        pass
    print(f"asyncio: {first:.3f} then {second:.3f} then {time.monotonic() - t0:.3f}", flush=True)


asyncio.run(main())
