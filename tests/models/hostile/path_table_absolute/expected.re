model\.yaml:10:22: simulation\.inputs\.force\.effort\.file: table `/etc/passwd` .+ \[PHC\-E116\]
