// Goroutines that read time.Now() in a loop for 0.1 s, as a control loop that keeps its period
// by watching the clock does. Go reads its clocks through the vDSO, which it looks up itself:
// each read must cost nanoseconds on simulated time, as natively, not a trapped system call.
package main

// #include <unistd.h>
import "C"

import (
	"fmt"
	"os"
	"strconv"
	"sync"
	"time"
)

func main() {
	spinners := 1
	if len(os.Args) > 1 {
		spinners, _ = strconv.Atoi(os.Args[1])
	}
	start := time.Now()
	var wg sync.WaitGroup
	reads := make([]int, spinners)
	backwards := make([]int, spinners)
	for i := 0; i < spinners; i++ {
		wg.Add(1)
		go func(i int) {
			defer wg.Done()
			last := time.Now()
			for {
				now := time.Now()
				reads[i]++
				if now.Before(last) {
					backwards[i]++
				}
				last = now
				if now.Sub(start) >= 100*time.Millisecond {
					return
				}
			}
		}(i)
	}
	wg.Wait()
	total, back, fewest := 0, 0, reads[0]
	for i := range reads {
		total += reads[i]
		back += backwards[i]
		if reads[i] < fewest {
			fewest = reads[i]
		}
	}
	fmt.Printf("clock loop: %d goroutines, each read the clock: %v, backwards %d, cgo %v\n", spinners, fewest > 1, back, C.getpid() > 0)
	fmt.Printf("clock loop: %d reads in %.3f ms\n", total, float64(time.Since(start).Microseconds())/1000)
}
