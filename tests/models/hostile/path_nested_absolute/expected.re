model\.yaml:4:29: components\.evil\.file: nested model .+ \[PHC\-E116\]
