scene\.yaml:2:8: model file `\.\./\.\./\.\./\.\./\.\./\.\./\.\./\.\./\.\./\.\./etc/passwd` lies outside .+ \[PHC-E116\]
