//go:build !cgo

package main

func callsC() bool {
	return false
}
