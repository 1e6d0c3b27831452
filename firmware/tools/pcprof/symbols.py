import sys, subprocess, bisect, collections
elf, prof = sys.argv[1], sys.argv[2]
out = subprocess.run(['llvm-nm','-n','--demangle','-S',elf],capture_output=True,text=True).stdout
syms=[]
for l in out.splitlines():
    p=l.split(None,3)
    if len(p)==4 and p[2].lower() in 't':
        syms.append((int(p[0],16),int(p[1],16),p[3]))
syms.sort(); addrs=[s[0] for s in syms]
tot=collections.Counter(); T=0
for l in open(prof):
    pc,n,c,ph=l.split(); pc=int(pc,16); w=int(n)*int(c)
    if len(sys.argv)>4 and ph!=sys.argv[4]: continue
    T+=w
    i=bisect.bisect_right(addrs,pc)-1
    name=syms[i][2] if i>=0 and pc<syms[i][0]+max(syms[i][1],1) else '?%x'%pc
    tot[name]+=w
print('total',T)
for k,v in tot.most_common(int(sys.argv[3]) if len(sys.argv)>3 else 40): print('%12d %5.1f%% %s'%(v,100*v/T,k[:150]))
