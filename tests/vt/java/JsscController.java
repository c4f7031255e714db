// A wheel controller as Java programs are written: jSSC (Debian's libjssc-java) for the port,
// a control loop on the main thread and a statistics thread fed through a BlockingQueue. With
// --until-stopped it runs until SIGTERM, as services do: a shutdown hook stops the loop and
// waits for its report.
import java.util.concurrent.BlockingQueue;
import java.util.concurrent.CountDownLatch;
import java.util.concurrent.LinkedBlockingQueue;
import java.util.concurrent.TimeUnit;
import jssc.SerialPort;
import jssc.SerialPortTimeoutException;

public class JsscController {
    static final int[] WHEELS = {1, 2, 3, 4};
    static volatile boolean stopping = false;

    static int crc16(byte[] data, int length) {
        int crc = 0;
        for (int i = 0; i < length; i++) {
            crc ^= (data[i] & 0xff) << 8;
            for (int bit = 0; bit < 8; bit++) crc = (crc & 0x8000) != 0 ? ((crc << 1) ^ 0x8005) & 0xffff : (crc << 1) & 0xffff;
        }
        return crc;
    }

    static byte[] packet(int id, int instruction, int... params) {
        int length = params.length + 3;
        byte[] out = new byte[10 + params.length];
        int[] head = {0xff, 0xff, 0xfd, 0x00, id, length & 0xff, length >> 8, instruction};
        for (int i = 0; i < head.length; i++) out[i] = (byte) head[i];
        for (int i = 0; i < params.length; i++) out[8 + i] = (byte) params[i];
        int crc = crc16(out, 8 + params.length);
        out[8 + params.length] = (byte) (crc & 0xff);
        out[9 + params.length] = (byte) (crc >> 8);
        return out;
    }

    /** One status packet, or null if none came within the timeout. */
    static byte[] status(SerialPort port, int timeoutMs) throws Exception {
        try {
            byte[] head = port.readBytes(7, timeoutMs);
            int rest = (head[5] & 0xff) | ((head[6] & 0xff) << 8);
            port.readBytes(rest, timeoutMs);
            return head;
        } catch (SerialPortTimeoutException timeout) {
            return null;
        }
    }

    record Cycle(double atMs, int answered) {}

    public static void main(String[] args) throws Exception {
        SerialPort port = new SerialPort(System.getenv("DXL_PORT"));
        port.openPort();
        port.setParams(Integer.parseInt(System.getenv().getOrDefault("DXL_BAUD", "57600")), 8, 1, 0);
        int found = 0;
        for (int id = 1; id <= 8; id++) {
            port.writeBytes(packet(id, 0x01));
            if (status(port, 10) != null) found++;
        }
        System.out.println("ping 1-8: " + found + " found");

        BlockingQueue<Cycle> queue = new LinkedBlockingQueue<>();
        Thread stats = new Thread(() -> {
            int cycles = 0, answered = 0, timeouts = 0;
            try {
                while (true) {
                    Cycle cycle = queue.poll(7, TimeUnit.MILLISECONDS);
                    if (cycle == null) { timeouts++; continue; }
                    if (cycle.answered() < 0) break;
                    cycles++;
                    answered += cycle.answered();
                }
            } catch (InterruptedException e) {
                return;
            }
            System.out.println("stats: " + cycles + " cycles, " + answered + " replies");
        });
        stats.start();

        boolean untilStopped = args.length > 0 && args[0].equals("--until-stopped");
        CountDownLatch reported = new CountDownLatch(1);
        if (untilStopped) {
            Runtime.getRuntime().addShutdownHook(new Thread(() -> {
                stopping = true;
                try { reported.await(); } catch (InterruptedException e) { }
            }));
        }
        long start = System.nanoTime();
        long next = start;
        long longest = 0, previous = start;
        int cycle = 0;
        for (; untilStopped ? !stopping : cycle < 100; cycle++) {
            next += 20_000_000L;
            port.writeBytes(packet(0xfe, 0x82, 128, 0, 4, 0, 1, 2, 3, 4));
            int answered = 0;
            for (int w = 0; w < WHEELS.length; w++) if (status(port, 10) != null) answered++;
            int goal = (cycle % 50) * 2;
            int[] params = new int[4 + 5 * WHEELS.length];
            params[0] = 104; params[2] = 4;
            for (int w = 0; w < WHEELS.length; w++) { params[4 + 5 * w] = WHEELS[w]; params[5 + 5 * w] = goal; }
            port.writeBytes(packet(0xfe, 0x83, params));
            queue.put(new Cycle((System.nanoTime() - start) / 1e6, answered));
            long wait = next - System.nanoTime();
            if (wait > 0) Thread.sleep(wait / 1_000_000, (int) (wait % 1_000_000));
            long now = System.nanoTime();
            longest = Math.max(longest, now - previous);
            previous = now;
        }
        queue.put(new Cycle(0, -1));
        stats.join();
        if (untilStopped) {
            // Stopped, the report comes after the run's end, on the wall clock: no time of it is told.
            System.out.printf("loop: %d cycles, longest period %.3f ms%n", cycle, longest / 1e6);
        } else {
            System.out.printf("loop: %d cycles in %.3f ms, longest period %.3f ms%n", cycle, (System.nanoTime() - start) / 1e6, longest / 1e6);
        }
        port.closePort();
        reported.countDown();
    }
}
