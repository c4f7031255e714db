// A wheel controller as Node.js programs are written: npm's serialport, promises and timers on
// libuv's loop, and a statistics worker thread fed with postMessage. It ends after 100 cycles;
// with --until-stopped it runs until SIGTERM, as services do, and reports then.
'use strict';
const { SerialPort } = require('serialport');
const { Worker } = require('worker_threads');

function crc16(bytes) {
  let crc = 0;
  for (const b of bytes) {
    crc ^= b << 8;
    for (let i = 0; i < 8; i++) crc = crc & 0x8000 ? ((crc << 1) ^ 0x8005) & 0xffff : (crc << 1) & 0xffff;
  }
  return crc;
}
function packet(id, instruction, params) {
  const len = params.length + 3;
  const body = [0xff, 0xff, 0xfd, 0x00, id, len & 0xff, len >> 8, instruction, ...params];
  const crc = crc16(body);
  return Buffer.from([...body, crc & 0xff, crc >> 8]);
}
const u16 = (v) => [v & 0xff, (v >> 8) & 0xff];
const u32 = (v) => [v & 0xff, (v >> 8) & 0xff, (v >> 16) & 0xff, (v >>> 24) & 0xff];

const WHEELS = [1, 2, 3, 4];
const port = new SerialPort({ path: process.env.DXL_PORT, baudRate: Number(process.env.DXL_BAUD || 57600) });
let rx = Buffer.alloc(0);
let pending = null;
port.on('data', (chunk) => {
  rx = Buffer.concat([rx, chunk]);
  for (;;) {
    const start = rx.indexOf(Buffer.from([0xff, 0xff, 0xfd, 0x00]));
    if (start < 0 || rx.length < start + 7) break;
    const total = 7 + rx.readUInt16LE(start + 5);
    if (rx.length < start + total) break;
    const reply = rx.subarray(start, start + total);
    rx = rx.subarray(start + total);
    if (pending) {
      pending.replies.push(reply);
      if (pending.replies.length === pending.expected) pending.done();
    }
  }
});
function transact(bytes, expected, timeoutMs) {
  return new Promise((resolve) => {
    const replies = [];
    const timer = setTimeout(() => { pending = null; resolve(replies); }, timeoutMs);
    pending = { replies, expected, done: () => { clearTimeout(timer); pending = null; resolve(replies); } };
    port.write(bytes);
  });
}

const stats = new Worker(`
  const { parentPort } = require('worker_threads');
  let cycles = 0, answered = 0;
  parentPort.on('message', (m) => {
    if (m === 'end') { parentPort.postMessage(\`stats: \${cycles} cycles, \${answered} replies\`); process.exit(0); }
    cycles += 1; answered += m.answered;
  });`, { eval: true });

function report(cycles, start, longest) {
  stats.postMessage('end');
  stats.once('message', (line) => {
    console.log(line);
    // Stopped, the report comes after the run's end, on the wall clock: no time of it is told.
    const took = untilStopped ? '' : ` in ${(performance.now() - start).toFixed(3)} ms`;
    console.log(`loop: ${cycles} cycles${took}, longest period ${longest.toFixed(3)} ms`);
    port.close(() => process.exit(0));
  });
}

const untilStopped = process.argv.includes('--until-stopped');
port.on('open', async () => {
  let found = 0;
  for (let id = 1; id <= 8; id++) found += (await transact(packet(id, 0x01, []), 1, 10)).length;
  console.log(`ping 1-8: ${found} found`);
  const syncRead = packet(0xfe, 0x82, [...u16(128), ...u16(4), ...WHEELS]);
  const start = performance.now();
  let previous = start, longest = 0, cycles = 0;
  const timer = setInterval(async () => {
    const now = performance.now();
    longest = Math.max(longest, now - previous);
    previous = now;
    const replies = await transact(syncRead, WHEELS.length, 10);
    const goal = (cycles % 50) * 2;
    port.write(packet(0xfe, 0x83, [...u16(104), ...u16(4), ...WHEELS.flatMap((id) => [id, ...u32(goal)])]));
    stats.postMessage({ at: now - start, answered: replies.length });
    cycles += 1;
    if (cycles === 100 && !untilStopped) {
      clearInterval(timer);
      report(cycles, start, longest);
    }
  }, 20);
  if (untilStopped) {
    process.on('SIGTERM', () => {
      clearInterval(timer);
      report(cycles, start, longest);
    });
  }
});
