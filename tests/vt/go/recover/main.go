// A Go program that recovers from a nil dereference (Go's own SIGSEGV handler turns the fault
// into a panic: the shim, which keeps SIGSEGV for rdtsc, must hand it on) and ends at once,
// while its runtime may still be starting threads.
package main

// #include <unistd.h>
import "C"

import "fmt"

type wheel struct{ id int }

func idOf(w *wheel) (id int, err error) {
	defer func() {
		if r := recover(); r != nil {
			err = fmt.Errorf("%v", r)
		}
	}()
	return w.id, nil
}

func main() {
	_, err := idOf(nil)
	fmt.Println("recovered:", err, C.getpid() > 0)
}
