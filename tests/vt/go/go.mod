module climbsim/vt-go

go 1.19
