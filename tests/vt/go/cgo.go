//go:build cgo

package main

// #include <unistd.h>
import "C"

// callsC makes a call into C through cgo, as a program that links a C library does.
func callsC() bool {
	return C.getpid() > 0
}
