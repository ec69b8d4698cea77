model\.yaml:10:22: simulation\.inputs\.force\.effort\.file: table `\.\./\.\./\.\./\.\./\.\./\.\./\.\./\.\./proc/self/environ` .+ \[PHC\-E116\]
