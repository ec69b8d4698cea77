model\.yaml:10:22: simulation\.inputs\.force\.effort\.file: table `table\.csv` .+ \[PHC\-E213\]
