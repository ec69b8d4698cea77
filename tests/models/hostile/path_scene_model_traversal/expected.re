scene\.yaml:2:8: model: .+ \[PHC-E1\d\d\]
