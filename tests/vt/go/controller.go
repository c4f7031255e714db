// A wheel controller as Go programs are written: the port opened with os.OpenFile (Go's
// netpoller watches it with epoll) and set raw with the termios ioctls, replies awaited with
// SetReadDeadline, a control loop on time.Sleep and a statistics goroutine fed through a
// channel, with select timeouts. Built with cgo (cgo.go: dynamically linked, its threads made
// by libc) it runs on virtual time; built without, it is static, and refused. It ends after 100
// cycles; with --until-stopped it runs until SIGTERM (os/signal), as services do, and reports then.
package main

import (
	"errors"
	"fmt"
	"os"
	"os/signal"
	"strconv"
	"syscall"
	"time"
	"unsafe"
)

var wheels = []byte{1, 2, 3, 4}

func crc16(data []byte) uint16 {
	var crc uint16
	for _, b := range data {
		crc ^= uint16(b) << 8
		for bit := 0; bit < 8; bit++ {
			if crc&0x8000 != 0 {
				crc = crc<<1 ^ 0x8005
			} else {
				crc <<= 1
			}
		}
	}
	return crc
}

func packet(id, instruction byte, params ...byte) []byte {
	length := len(params) + 3
	out := []byte{0xff, 0xff, 0xfd, 0x00, id, byte(length), byte(length >> 8), instruction}
	out = append(out, params...)
	crc := crc16(out)
	return append(out, byte(crc), byte(crc>>8))
}

var baudRates = map[int]uint32{57600: syscall.B57600, 115200: syscall.B115200, 1000000: 0o010010}

// makeRaw sets the terminal raw at the given rate, as a serial library does (through
// SyscallConn: File.Fd would put the descriptor back in blocking mode, out of the netpoller).
func makeRaw(port *os.File, baud int) error {
	speed, ok := baudRates[baud]
	if !ok {
		return fmt.Errorf("unsupported baud rate %d", baud)
	}
	conn, err := port.SyscallConn()
	if err != nil {
		return err
	}
	var ioctlErr error
	err = conn.Control(func(fd uintptr) { ioctlErr = setRaw(fd, speed) })
	if err != nil {
		return err
	}
	return ioctlErr
}

func setRaw(fd uintptr, speed uint32) error {
	var tio syscall.Termios
	if _, _, errno := syscall.Syscall(syscall.SYS_IOCTL, fd, syscall.TCGETS, uintptr(unsafe.Pointer(&tio))); errno != 0 {
		return errno
	}
	tio.Iflag = 0
	tio.Oflag = 0
	tio.Lflag = 0
	tio.Cflag = syscall.CS8 | syscall.CREAD | syscall.CLOCAL | speed
	tio.Ispeed, tio.Ospeed = speed, speed
	tio.Cc[syscall.VMIN], tio.Cc[syscall.VTIME] = 1, 0
	if _, _, errno := syscall.Syscall(syscall.SYS_IOCTL, fd, syscall.TCSETS, uintptr(unsafe.Pointer(&tio))); errno != 0 {
		return errno
	}
	return nil
}

// readFull reads exactly len(buf) bytes before the deadline.
func readFull(port *os.File, buf []byte, deadline time.Time) bool {
	if err := port.SetReadDeadline(deadline); err != nil {
		panic(err)
	}
	for got := 0; got < len(buf); {
		n, err := port.Read(buf[got:])
		got += n
		if errors.Is(err, os.ErrDeadlineExceeded) {
			return false
		} else if err != nil {
			panic(err)
		}
	}
	return true
}

// status reads one status packet; false if none came within the timeout.
func status(port *os.File, timeout time.Duration) bool {
	deadline := time.Now().Add(timeout)
	head := make([]byte, 7)
	if !readFull(port, head, deadline) {
		return false
	}
	rest := int(head[5]) | int(head[6])<<8
	return readFull(port, make([]byte, rest), deadline)
}

type cycle struct {
	atMs     float64
	answered int
}

func main() {
	port, err := os.OpenFile(os.Getenv("DXL_PORT"), os.O_RDWR|syscall.O_NOCTTY, 0)
	if err != nil {
		panic(err)
	}
	baud, err := strconv.Atoi(os.Getenv("DXL_BAUD"))
	if err != nil {
		baud = 57600
	}
	if err := makeRaw(port, baud); err != nil {
		panic(err)
	}
	fmt.Printf("go with cgo: %v\n", callsC())
	found := 0
	for id := byte(1); id <= 8; id++ {
		port.Write(packet(id, 0x01))
		if status(port, 10*time.Millisecond) {
			found++
		}
	}
	fmt.Printf("ping 1-8: %d found\n", found)

	cycles := make(chan cycle)
	done := make(chan struct{})
	go func() {
		count, answered, timeouts := 0, 0, 0
		for {
			select {
			case c := <-cycles:
				if c.answered < 0 {
					fmt.Printf("stats: %d cycles, %d replies\n", count, answered)
					close(done)
					return
				}
				count++
				answered += c.answered
			case <-time.After(7 * time.Millisecond):
				timeouts++
			}
		}
	}()

	untilStopped := len(os.Args) > 1 && os.Args[1] == "--until-stopped"
	stop := make(chan os.Signal, 1)
	if untilStopped {
		signal.Notify(stop, syscall.SIGTERM)
	}
	start := time.Now()
	next := start
	previous := start
	var longest time.Duration
	n := 0
loop:
	for ; n < 100 || untilStopped; n++ {
		next = next.Add(20 * time.Millisecond)
		port.Write(packet(0xfe, 0x82, 128, 0, 4, 0, 1, 2, 3, 4))
		answered := 0
		for range wheels {
			if status(port, 10*time.Millisecond) {
				answered++
			}
		}
		goal := byte(n%50) * 2
		params := []byte{104, 0, 4, 0}
		for _, id := range wheels {
			params = append(params, id, goal, 0, 0, 0)
		}
		port.Write(packet(0xfe, 0x83, params...))
		cycles <- cycle{float64(time.Since(start).Microseconds()) / 1e3, answered}
		if !untilStopped {
			time.Sleep(time.Until(next))
		} else {
			select {
			case <-stop:
				n++
				break loop
			case <-time.After(time.Until(next)):
			}
		}
		now := time.Now()
		if now.Sub(previous) > longest {
			longest = now.Sub(previous)
		}
		previous = now
	}
	cycles <- cycle{0, -1}
	<-done
	if untilStopped {
		// Stopped, the report comes after the run's end, on the wall clock: no time of it is told.
		fmt.Printf("loop: %d cycles, longest period %.3f ms\n", n, float64(longest.Nanoseconds())/1e6)
	} else {
		fmt.Printf("loop: %d cycles in %.3f ms, longest period %.3f ms\n", n, float64(time.Since(start).Nanoseconds())/1e6, float64(longest.Nanoseconds())/1e6)
	}
	port.Close()
}
